#include "canopen/ascii_response.hpp"

#include <cstdio>

namespace canbridge::canopen {

namespace {
// Text taken from elsewhere (an abort's detail, a file name) must not break the line format.
std::string one_line(std::string_view text) {
  std::string out(text);
  for (char& c : out) {
    if (c == '\r' || c == '\n' || c == '\0') c = ' ';
  }
  return out;
}
}  // namespace

std::string ascii_prefix(std::optional<std::uint32_t> sequence) {
  return sequence ? "[" + std::to_string(*sequence) + "] " : std::string();
}

std::string ascii_line(std::optional<std::uint32_t> sequence, std::string_view text) {
  std::string out = ascii_prefix(sequence);
  out += text;
  out += "\r\n";
  return out;
}

std::string ascii_ok(std::optional<std::uint32_t> sequence) {
  return ascii_line(sequence, "OK");
}

std::string_view ascii_abort_text(std::uint32_t code) {
  // The descriptions CiA 309-3 gateways print after an SDO abort code, in the wording of
  // CANopenNode's gateway (CO_gateway_ascii.c), the de-facto reference that scripts and its
  // `cocomm` tool compare lines against. The canopen.sdo category keeps its own, longer texts
  // for logs; these are the protocol's.
  switch (code) {
    case 0x00000000:
      return "No abort.";
    case 0x05030000:
      return "Toggle bit not altered.";
    case 0x05040000:
      return "SDO protocol timed out.";
    case 0x05040001:
      return "Command specifier not valid or unknown.";
    case 0x05040002:
      return "Invalid block size in block mode.";
    case 0x05040003:
      return "Invalid sequence number in block mode.";
    case 0x05040004:
      return "CRC error (block mode only).";
    case 0x05040005:
      return "Out of memory.";
    case 0x06010000:
      return "Unsupported access to an object.";
    case 0x06010001:
      return "Attempt to read a write only object.";
    case 0x06010002:
      return "Attempt to write a read only object.";
    case 0x06020000:
      return "Object does not exist.";
    case 0x06040041:
      return "Object cannot be mapped to the PDO.";
    case 0x06040042:
      return "Number and length of object to be mapped exceeds PDO length.";
    case 0x06040043:
      return "General parameter incompatibility reasons.";
    case 0x06040047:
      return "General internal incompatibility in device.";
    case 0x06060000:
      return "Access failed due to hardware error.";
    case 0x06070010:
      return "Data type does not match, length of service parameter does not match.";
    case 0x06070012:
      return "Data type does not match, length of service parameter too high.";
    case 0x06070013:
      return "Data type does not match, length of service parameter too short.";
    case 0x06090011:
      return "Sub index does not exist.";
    case 0x06090030:
      return "Invalid value for parameter (download only).";
    case 0x06090031:
      return "Value range of parameter written too high.";
    case 0x06090032:
      return "Value range of parameter written too low.";
    case 0x06090036:
      return "Maximum value is less than minimum value.";
    case 0x060A0023:
      return "Resource not available: SDO connection.";
    case 0x08000000:
      return "General error.";
    case 0x08000020:
      return "Data cannot be transferred or stored to application.";
    case 0x08000021:
      return "Data cannot be transferred or stored to application because of local control.";
    case 0x08000022:
      return "Data cannot be transferred or stored to application because of present device "
             "state.";
    case 0x08000023:
      return "Object dictionary not present or dynamic generation fails.";
    case 0x08000024:
      return "No data available.";
    default:
      return "-";  // the reference's text for a code it does not know
  }
}

std::string ascii_sdo_abort(std::optional<std::uint32_t> sequence, std::uint32_t code,
                            std::string_view detail) {
  char head[32];
  std::snprintf(head, sizeof head, "ERROR:0x%08X #", code);
  std::string text = head;
  text += ascii_abort_text(code);
  if (!detail.empty()) text += " " + one_line(detail);
  return ascii_line(sequence, text);
}

std::string ascii_error(std::optional<std::uint32_t> sequence, AsciiError error,
                        std::string_view detail) {
  std::string text = "ERROR:" + std::to_string(static_cast<unsigned>(error)) + " #";
  text += ascii_error_text(error);
  if (!detail.empty()) text += " " + one_line(detail);
  return ascii_line(sequence, text);
}

std::string ascii_multiline(std::optional<std::uint32_t> sequence,
                            const std::vector<std::string>& lines) {
  std::string out;
  for (const std::string& line : lines) {
    out += one_line(line);
    out += '\n';
  }
  return out + ascii_ok(sequence);
}

}  // namespace canbridge::canopen
