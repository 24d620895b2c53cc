#include "canopen/ascii_response.hpp"

#include <cstdio>

#include "canopen/sdo_abort.hpp"

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

std::string ascii_line(std::optional<std::uint32_t> sequence, std::string_view text) {
  std::string out;
  if (sequence) out = "[" + std::to_string(*sequence) + "] ";
  out += text;
  out += "\r\n";
  return out;
}

std::string ascii_ok(std::optional<std::uint32_t> sequence) {
  return ascii_line(sequence, "OK");
}

std::string ascii_sdo_abort(std::optional<std::uint32_t> sequence, std::uint32_t code,
                            std::string_view detail) {
  char head[32];
  std::snprintf(head, sizeof head, "ERROR: 0x%08X #", code);
  std::string text = head;
  if (!detail.empty()) text += one_line(detail) + ": ";
  text += one_line(abort_error(code).message());
  return ascii_line(sequence, text);
}

std::string ascii_error(std::optional<std::uint32_t> sequence, AsciiError error,
                        std::string_view detail) {
  std::string text = "ERROR: " + std::to_string(static_cast<unsigned>(error)) + " #";
  text += ascii_error_text(error);
  if (!detail.empty()) text += " " + one_line(detail);
  return ascii_line(sequence, text);
}

}  // namespace canbridge::canopen
