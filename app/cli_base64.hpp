// Base64 (RFC 4648, with padding) for the endpoint's domain and octet-string values, which CiA
// 309-3 carries on one line.
#pragma once

#include <string>
#include <string_view>

namespace canbridge::cli {

std::string base64_encode(std::string_view bytes);
// False (and `bytes` unspecified) on a character outside the alphabet or a bad length.
bool base64_decode(std::string_view text, std::string& bytes);

}  // namespace canbridge::cli
