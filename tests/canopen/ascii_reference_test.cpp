// canbridge's CiA 309-3 answers against the lines the de-facto reference gateway writes.
// CANopenNode's gateway (309/CO_gateway_ascii.c) documents its answers as
// `"[" <sequence> "]" OK | <value> | ERROR:<SDO-abort-code> | ERROR:<internal-error-code>`
// and prints them with the formats `[%d] ERROR:0x%08X #%s\r\n` and `[%d] ERROR:%d #%s\r\n`,
// the text being its description of the code. The expected lines below are written from that
// format and those descriptions, not from canbridge's output: a script or a `cocomm` session
// that works against CANopenNode's `canopend` must read canbridge's answers the same way.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <string>

#include "canopen/ascii_command.hpp"
#include "canopen/ascii_response.hpp"

namespace canbridge::canopen {
namespace {

struct Reference {
  std::uint32_t code;
  const char* description;
};

std::string reference_abort_line(std::uint32_t seq, const Reference& r) {
  char line[160];
  std::snprintf(line, sizeof line, "[%u] ERROR:0x%08X #%s\r\n", static_cast<unsigned>(seq),
                static_cast<unsigned>(r.code), r.description);
  return line;
}

std::string reference_error_line(std::uint32_t seq, const Reference& r) {
  char line[160];
  std::snprintf(line, sizeof line, "[%u] ERROR:%u #%s\r\n", static_cast<unsigned>(seq),
                static_cast<unsigned>(r.code), r.description);
  return line;
}

TEST(AsciiReference, SdoAbortLinesAreTheReferenceGatewaysByteForByte) {
  const Reference aborts[] = {
      {0x05030000, "Toggle bit not altered."},
      {0x05040000, "SDO protocol timed out."},
      {0x05040001, "Command specifier not valid or unknown."},
      {0x05040002, "Invalid block size in block mode."},
      {0x05040003, "Invalid sequence number in block mode."},
      {0x05040004, "CRC error (block mode only)."},
      {0x05040005, "Out of memory."},
      {0x06010000, "Unsupported access to an object."},
      {0x06010001, "Attempt to read a write only object."},
      {0x06010002, "Attempt to write a read only object."},
      {0x06020000, "Object does not exist."},
      {0x06040041, "Object cannot be mapped to the PDO."},
      {0x06040042, "Number and length of object to be mapped exceeds PDO length."},
      {0x06040043, "General parameter incompatibility reasons."},
      {0x06040047, "General internal incompatibility in device."},
      {0x06060000, "Access failed due to hardware error."},
      {0x06070010, "Data type does not match, length of service parameter does not match."},
      {0x06070012, "Data type does not match, length of service parameter too high."},
      {0x06070013, "Data type does not match, length of service parameter too short."},
      {0x06090011, "Sub index does not exist."},
      {0x06090030, "Invalid value for parameter (download only)."},
      {0x06090031, "Value range of parameter written too high."},
      {0x06090032, "Value range of parameter written too low."},
      {0x06090036, "Maximum value is less than minimum value."},
      {0x060A0023, "Resource not available: SDO connection."},
      {0x08000000, "General error."},
      {0x08000020, "Data cannot be transferred or stored to application."},
      {0x08000021, "Data cannot be transferred or stored to application because of local control."},
      {0x08000022,
       "Data cannot be transferred or stored to application because of present device state."},
      {0x08000023, "Object dictionary not present or dynamic generation fails."},
      {0x08000024, "No data available."},
      {0x0BADC0DE, "-"},  // a code the reference does not list
  };
  std::uint32_t seq = 1;
  for (const Reference& r : aborts) {
    EXPECT_EQ(ascii_sdo_abort(seq, r.code), reference_abort_line(seq, r));
    ++seq;
  }
}

TEST(AsciiReference, GatewayErrorLinesAreTheReferenceGatewaysByteForByte) {
  const Reference errors[] = {
      {100, "Request not supported."},
      {101, "Syntax error."},
      {102, "Request not processed due to internal state."},
      {103, "Time-out."},
      {104, "No default net set."},
      {105, "No default node set."},
      {106, "Unsupported net."},
      {107, "Unsupported node."},
      {201, "Lost connection."},
  };
  for (const Reference& r : errors) {
    EXPECT_EQ(ascii_error(42u, static_cast<AsciiError>(r.code)), reference_error_line(42u, r));
  }
}

TEST(AsciiReference, AMatcherForTheReferenceFormFindsEveryCanbridgeError) {
  // The pattern scripts written for canopend use: "ERROR:0x" right after the sequence.
  const std::string with_detail = ascii_sdo_abort(5u, 0x05040000, "no answer from gateway");
  EXPECT_EQ(with_detail.rfind("[5] ERROR:0x05040000 #SDO protocol timed out.", 0), 0u)
      << with_detail;
  const std::string error = ascii_error(6u, AsciiError::timeout, "no answer from gateway");
  EXPECT_EQ(error.rfind("[6] ERROR:103 #Time-out.", 0), 0u) << error;
}

TEST(AsciiReference, AMultiLineAnswerHasOneCrLfAtItsEnd) {
  // cocomm prints an answer up to the first CR LF it reads: the reference's help separates its
  // lines with LF and closes with CR LF, and so must every multi-line answer.
  const std::string help = ascii_multiline(3u, ascii_help(""));
  ASSERT_GT(help.size(), 2u);
  EXPECT_EQ(help.find("\r\n"), help.size() - 2) << help;
  EXPECT_EQ(help.substr(help.rfind('\n', help.size() - 3) + 1), "[3] OK\r\n");
  EXPECT_NE(help.find("help [datatype|lss]"), std::string::npos);
  EXPECT_GT(std::count(help.begin(), help.end(), '\n'), 10);
}

}  // namespace
}  // namespace canbridge::canopen
