// A gateway's pre-shared keys and the key file they come from, loaded only when the file's
// permissions keep it private to the process's user.
#pragma once

#include <sys/stat.h>
#include <sys/types.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace canbridge::backbone {

inline constexpr std::size_t kPreSharedKeySize = 32;
// A key file holds the current key and, while keys are being rotated, one more (docs/security.md).
inline constexpr std::size_t kMaxKeysPerFile = 2;
// Far more than two keys and a page of comments; a bigger file is not a key file.
inline constexpr std::size_t kMaxKeyFileSize = 16 * 1024;

// 32 secret bytes; wiped from memory when destroyed so copies do not linger in freed heap.
class PreSharedKey {
 public:
  explicit PreSharedKey(std::span<const std::uint8_t, kPreSharedKeySize> bytes);
  PreSharedKey(const PreSharedKey&) = default;
  PreSharedKey& operator=(const PreSharedKey&) = default;
  ~PreSharedKey();

  std::span<const std::uint8_t, kPreSharedKeySize> bytes() const { return bytes_; }

 private:
  std::array<std::uint8_t, kPreSharedKeySize> bytes_;
};

enum class KeyFileError {
  cannot_open = 1,
  not_a_regular_file,
  too_open,     // group or others have some access
  wrong_owner,  // owned by neither the process's user nor root
  too_large,
  malformed,  // a line that is neither a comment nor 64 hex digits
  no_key,
  too_many_keys,
};
const std::error_category& key_file_category() noexcept;
std::error_code make_error_code(KeyFileError e) noexcept;

// Why a key file was refused. `message` names the file, what is wrong and the fix, and never
// quotes the file's content (it may be a key with a typo in it).
struct KeyFileProblem {
  std::error_code error;
  int line = 0;  // 1-based line of a malformed entry; 0 when about the whole file
  std::string message;
};

// The keys of one file, current key first, or the problem that refused it.
struct KeyFileResult {
  std::vector<PreSharedKey> keys;  // empty when problem is set
  std::optional<KeyFileProblem> problem;
  explicit operator bool() const noexcept { return !problem; }
};

// The key file format: UTF-8 text; blank lines and everything from a '#' to the end of the line
// are ignored; every other line is one key, exactly 64 hex digits (either case) with optional
// surrounding spaces, as written by `openssl rand -hex 32`. One or kMaxKeysPerFile keys; the
// first is the one this end proves with.
KeyFileResult parse_key_file(std::string_view text, const std::string& file);

// The permission rule, given the file's status and the process's effective user: a regular file,
// owned by that user or by root, with no permission bits for group or others (mode 0600 or 0400).
std::optional<KeyFileProblem> check_key_file_permissions(const struct stat& status,
                                                         uid_t process_user,
                                                         const std::string& file);

// Opens `path`, checks its permissions on the opened file (so a swap after the check cannot
// slip through) and parses it. Symbolic links are followed; the rule applies to their target.
KeyFileResult load_key_file(const std::string& path);

}  // namespace canbridge::backbone

template <>
struct std::is_error_code_enum<canbridge::backbone::KeyFileError> : std::true_type {};
