// The response lines of a CiA 309-3 ASCII command endpoint (`[<seq>] OK`, a value, `ERROR:...`),
// so that every answer has one format: CR LF at the end, and the request's sequence echoed when
// it had one.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "canopen/ascii_command.hpp"

namespace canbridge::canopen {

// `[<seq>] <text>` CR LF; just `<text>` CR LF without a sequence.
std::string ascii_line(std::optional<std::uint32_t> sequence, std::string_view text);
// `[<seq>] `, or nothing without a sequence: what starts every line of an answer.
std::string ascii_prefix(std::optional<std::uint32_t> sequence);
// `[<seq>] OK`
std::string ascii_ok(std::optional<std::uint32_t> sequence);
// The CiA 301 description of an SDO abort code as CiA 309-3 gateways print it after `#` (the
// wording of CANopenNode's gateway, byte for byte); "-" for a code it does not list.
std::string_view ascii_abort_text(std::uint32_t code);
// `[<seq>] ERROR:0x<8 hex digits> #<description>` (CANopenNode's form, so that scripts matching
// `ERROR:0x` work with either), followed by ` <detail>` when there is one (e.g. the flash step
// that failed): the detail stays in the comment after `#`, which no parser reads as the code.
std::string ascii_sdo_abort(std::optional<std::uint32_t> sequence, std::uint32_t code,
                            std::string_view detail = {});
// `[<seq>] ERROR:<n> #<standard text>`, followed by ` <detail>` when there is one.
std::string ascii_error(std::optional<std::uint32_t> sequence, AsciiError error,
                        std::string_view detail = {});
// A multi-line answer (help, the node table): its lines separated by LF alone, and the closing
// `[<seq>] OK` CR LF. CR LF ends an answer in CiA 309-3 (CANopenNode's gateway frames its help
// the same way), and a client such as cocomm prints one answer per CR LF: lines each ending in
// CR LF were cut off after the first.
std::string ascii_multiline(std::optional<std::uint32_t> sequence,
                            const std::vector<std::string>& lines);

}  // namespace canbridge::canopen
