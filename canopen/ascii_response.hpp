// The response lines of a CiA 309-3 ASCII command endpoint (`[<seq>] OK`, a value, `ERROR: ...`),
// so that every answer has one format: CR LF at the end, and the request's sequence echoed when
// it had one.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "canopen/ascii_command.hpp"

namespace canbridge::canopen {

// `[<seq>] <text>` CR LF; just `<text>` CR LF without a sequence.
std::string ascii_line(std::optional<std::uint32_t> sequence, std::string_view text);
// `[<seq>] OK`
std::string ascii_ok(std::optional<std::uint32_t> sequence);
// `[<seq>] ERROR: 0x<8 hex digits> #<text>`, the text of the SdoAbort category for `code`,
// prefixed with `detail: ` when there is one (e.g. the flash step that failed).
std::string ascii_sdo_abort(std::optional<std::uint32_t> sequence, std::uint32_t code,
                            std::string_view detail = {});
// `[<seq>] ERROR: <n> #<standard text>`, followed by ` <detail>` when there is one.
std::string ascii_error(std::optional<std::uint32_t> sequence, AsciiError error,
                        std::string_view detail = {});

}  // namespace canbridge::canopen
