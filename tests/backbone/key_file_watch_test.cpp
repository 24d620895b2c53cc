// KeyFileWatch: keys rotate in the file without a restart, and a broken edit keeps the last good
// keys.
#include "backbone/key_file_watch.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <fstream>
#include <stdexcept>
#include <string>

#include "backbone/peer_authenticator.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge::backbone {
namespace {

std::string hex_of(const PreSharedKey& key) {
  static const char* digits = "0123456789abcdef";
  std::string hex;
  for (std::uint8_t b : key.bytes()) {
    hex += digits[b >> 4];
    hex += digits[b & 0xF];
  }
  return hex;
}

std::string content_of(const std::string& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), {}};
}

TEST(KeyFileWatch, AKeyAppendedAndThenRemovedIsSeenAtTheNextUse) {
  test::TempKeyDir dir;
  const std::string path = dir.key("gw1.key");
  KeyFileWatch watch(path);
  ASSERT_EQ(watch.keys().size(), 1u);
  const KeyId old_id = key_id(watch.keys()[0]);

  // Rotation step 1 on the surface: the new key goes in as the second line.
  const std::string old_line = content_of(path);
  test::TempKeyDir other;
  const std::string next_line = content_of(other.key("next.key"));
  dir.file("gw1.key", old_line + next_line);
  ASSERT_EQ(watch.keys().size(), 2u);
  EXPECT_EQ(key_id(watch.keys()[0]), old_id);
  const KeyId new_id = key_id(watch.keys()[1]);
  EXPECT_NE(new_id, old_id);

  // Step 3: the old key leaves.
  dir.file("gw1.key", next_line);
  ASSERT_EQ(watch.keys().size(), 1u);
  EXPECT_EQ(key_id(watch.keys()[0]), new_id);
  EXPECT_EQ(watch.reloads(), 2u);
  EXPECT_EQ(watch.refused_edits(), 0u);
}

TEST(KeyFileWatch, AnUnchangedFileIsNotReread) {
  test::TempKeyDir dir;
  KeyFileWatch watch(dir.key("gw1.key"));
  for (int i = 0; i < 100; ++i) ASSERT_EQ(watch.keys().size(), 1u);
  EXPECT_EQ(watch.reloads(), 0u);
}

TEST(KeyFileWatch, ABrokenEditKeepsTheLastGoodKeysUntilItIsFixed) {
  test::TempKeyDir dir;
  const std::string path = dir.key("gw1.key");
  KeyFileWatch watch(path);
  const std::string good = hex_of(watch.keys()[0]);

  dir.file("gw1.key", good.substr(0, 63) + "\n");  // a digit lost while editing
  ASSERT_EQ(watch.keys().size(), 1u);
  EXPECT_EQ(hex_of(watch.keys()[0]), good);
  EXPECT_EQ(watch.refused_edits(), 1u);

  dir.file("gw1.key", good + "\n", 0644);  // readable by others: refused as at start
  ASSERT_EQ(watch.keys().size(), 1u);
  EXPECT_EQ(hex_of(watch.keys()[0]), good);
  EXPECT_EQ(watch.refused_edits(), 2u);

  ASSERT_EQ(::chmod(path.c_str(), 0600), 0);  // the fix the warning names
  ASSERT_EQ(watch.keys().size(), 1u);
  EXPECT_EQ(watch.reloads(), 1u);
}

TEST(KeyFileWatch, AFileThatCannotBeUsedAtStartStopsTheStart) {
  test::TempKeyDir dir;
  EXPECT_THROW(KeyFileWatch(dir.key("open.key", 0644)), std::runtime_error);
  EXPECT_THROW(KeyFileWatch(dir.path() + "/missing.key"), std::runtime_error);
}

}  // namespace
}  // namespace canbridge::backbone
