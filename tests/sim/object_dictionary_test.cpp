#include "sim/object_dictionary.hpp"

#include <gtest/gtest.h>

#include "canopen/sdo_abort.hpp"

namespace canbridge::sim {
namespace {

using canopen::SdoAbort;
using Bytes = std::vector<std::uint8_t>;

ObjectDictionary sample() {
  ObjectDictionary od;
  od.add_unsigned(0x1000, 0, Access::constant, 0x00000191, 4);
  od.add_unsigned(0x1017, 0, Access::rw, 1000, 2);
  od.add_unsigned(0x1018, 0, Access::constant, 4, 1);
  od.add_unsigned(0x1018, 1, Access::ro, 0x12345678, 4);
  od.add_unsigned(0x2000, 0, Access::wo, 0, 1);
  return od;
}

TEST(ObjectDictionary, ReadReturnsLittleEndianBytes) {
  const ObjectDictionary od = sample();
  const auto r = od.read(0x1018, 1);
  ASSERT_FALSE(r.error);
  EXPECT_EQ(Bytes(r.value.begin(), r.value.end()), (Bytes{0x78, 0x56, 0x34, 0x12}));
  EXPECT_EQ(od.get_unsigned(0x1017, 0), 1000u);
}

TEST(ObjectDictionary, LookupErrorsDistinguishObjectFromSubIndex) {
  const ObjectDictionary od = sample();
  EXPECT_EQ(od.read(0x6000, 0).error, SdoAbort::no_object);
  EXPECT_EQ(od.read(0x1018, 5).error, SdoAbort::no_sub_index);
  EXPECT_EQ(od.read(0x1017, 1).error, SdoAbort::no_sub_index);
  EXPECT_TRUE(od.has_object(0x1018));
  EXPECT_FALSE(od.has_object(0x1019));
  EXPECT_EQ(od.read(0x2000, 0).error, SdoAbort::read_write_only);
}

TEST(ObjectDictionary, WriteChecksAccessThenLength) {
  ObjectDictionary od = sample();
  const Bytes two{0x64, 0x00};
  EXPECT_EQ(od.write(0x1000, 0, Bytes{1, 2, 3, 4}), SdoAbort::write_read_only);  // const
  EXPECT_EQ(od.write(0x1018, 1, Bytes{1, 2, 3, 4}), SdoAbort::write_read_only);  // ro
  EXPECT_EQ(od.write(0x1017, 0, Bytes{1, 2, 3, 4}), SdoAbort::length_too_high);
  EXPECT_EQ(od.write(0x1017, 0, Bytes{1}), SdoAbort::length_too_low);
  EXPECT_EQ(od.write(0x3000, 0, two), SdoAbort::no_object);
  EXPECT_FALSE(od.write(0x1017, 0, two));
  EXPECT_EQ(od.get_unsigned(0x1017, 0), 100u);
  EXPECT_FALSE(od.write(0x2000, 0, Bytes{7}));
}

TEST(ObjectDictionary, RestoreInitialHonoursTheRange) {
  ObjectDictionary od = sample();
  ASSERT_TRUE(od.set_unsigned(0x1017, 0, 5));
  ASSERT_TRUE(od.set_unsigned(0x2000, 0, 9));
  od.restore_initial(0x1000, 0x1FFF);
  EXPECT_EQ(od.get_unsigned(0x1017, 0), 1000u);
  EXPECT_EQ(od.get_unsigned(0x2000, 0), 9u);
  od.restore_initial();
  EXPECT_EQ(od.get_unsigned(0x2000, 0), 0u);
  EXPECT_FALSE(od.set_unsigned(0x5000, 0, 1));
}

TEST(ObjectDictionary, VariableLengthEntriesTakeAnyLengthUpToTheLimit) {
  ObjectDictionary od;
  od.add(0x2000, 0, Access::rw, DataType::domain, Bytes{1});
  EXPECT_FALSE(od.write(0x2000, 0, Bytes(1000, 0xAB)));
  EXPECT_EQ(od.find(0x2000, 0)->value.size(), 1000u);
  EXPECT_FALSE(od.write(0x2000, 0, Bytes{}));
  EXPECT_TRUE(od.find(0x2000, 0)->value.empty());
  EXPECT_EQ(od.write(0x2000, 0, Bytes(kMaxVariableBytes + 1, 0)), SdoAbort::out_of_memory);
  EXPECT_THROW(od.add(0x2001, 0, Access::rw, DataType::unsigned32, Bytes{1}),
               std::invalid_argument);
}

TEST(ObjectDictionary, GuardVetoesAndListenerSeesCommittedWrites) {
  ObjectDictionary od = sample();
  int heard = 0;
  od.set_write_guard([](const OdEntry& entry, std::span<const std::uint8_t> data) {
    return entry.index == 0x1017 && data[0] == 0xFF ? std::error_code(SdoAbort::value_range)
                                                    : std::error_code();
  });
  od.set_write_listener([&](const OdEntry& entry) { heard += entry.index == 0x1017; });
  EXPECT_EQ(od.write(0x1017, 0, Bytes{0xFF, 0}), SdoAbort::value_range);
  EXPECT_EQ(heard, 0);
  EXPECT_EQ(od.get_unsigned(0x1017, 0), 1000u);
  EXPECT_FALSE(od.write(0x1017, 0, Bytes{0x10, 0}));
  EXPECT_EQ(heard, 1);
}

TEST(ObjectDictionary, DataTypeNamesRoundTrip) {
  for (auto type : {DataType::boolean, DataType::integer16, DataType::unsigned32, DataType::real64,
                    DataType::visible_string, DataType::domain}) {
    EXPECT_EQ(parse_data_type(to_string(type)), type);
  }
  EXPECT_EQ(parse_data_type("uint32"), std::nullopt);
  EXPECT_EQ(fixed_size(DataType::unsigned64), 8u);
  EXPECT_TRUE(is_variable_length(DataType::visible_string));
}

}  // namespace
}  // namespace canbridge::sim
