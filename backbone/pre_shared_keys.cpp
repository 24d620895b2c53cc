#include "backbone/pre_shared_keys.hpp"

#include <fcntl.h>
#include <openssl/crypto.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace canbridge::backbone {

PreSharedKey::PreSharedKey(std::span<const std::uint8_t, kPreSharedKeySize> bytes) {
  std::memcpy(bytes_.data(), bytes.data(), bytes_.size());
}

PreSharedKey::~PreSharedKey() {
  OPENSSL_cleanse(bytes_.data(), bytes_.size());
}

namespace {

class KeyFileCategory : public std::error_category {
 public:
  const char* name() const noexcept override { return "key file"; }
  std::string message(int e) const override {
    switch (static_cast<KeyFileError>(e)) {
      case KeyFileError::cannot_open:
        return "cannot open key file";
      case KeyFileError::not_a_regular_file:
        return "key file is not a regular file";
      case KeyFileError::too_open:
        return "key file is accessible to group or others";
      case KeyFileError::wrong_owner:
        return "key file is owned by another user";
      case KeyFileError::too_large:
        return "key file is too large";
      case KeyFileError::malformed:
        return "key file has a malformed line";
      case KeyFileError::no_key:
        return "key file holds no key";
      case KeyFileError::too_many_keys:
        return "key file holds too many keys";
    }
    return "unknown key file error";
  }
};

KeyFileResult refuse(KeyFileError e, int line, std::string message) {
  KeyFileResult result;
  result.problem = KeyFileProblem{make_error_code(e), line, std::move(message)};
  return result;
}

std::string_view trim(std::string_view s) {
  const auto first = s.find_first_not_of(" \t\r");
  if (first == std::string_view::npos) return {};
  const auto last = s.find_last_not_of(" \t\r");
  return s.substr(first, last - first + 1);
}

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

std::string octal_mode(mode_t mode) {
  char text[8];
  std::snprintf(text, sizeof text, "%04o", static_cast<unsigned>(mode & 07777));
  return text;
}

}  // namespace

const std::error_category& key_file_category() noexcept {
  static const KeyFileCategory category;
  return category;
}

std::error_code make_error_code(KeyFileError e) noexcept {
  return {static_cast<int>(e), key_file_category()};
}

KeyFileResult parse_key_file(std::string_view text, const std::string& file) {
  static constexpr std::string_view kHowToMake = "; make a key with `openssl rand -hex 32`";
  KeyFileResult result;
  int line_number = 0;
  while (!text.empty()) {
    ++line_number;
    const auto end = text.find('\n');
    std::string_view line = text.substr(0, end);
    text = end == std::string_view::npos ? std::string_view{} : text.substr(end + 1);
    line = trim(line.substr(0, line.find('#')));
    if (line.empty()) continue;

    const std::string where = file + ":" + std::to_string(line_number) + ": ";
    // Positions and lengths only: the line may be a real key with one typo.
    if (line.size() != 2 * kPreSharedKeySize) {
      return refuse(KeyFileError::malformed, line_number,
                    where + "a key is 64 hex digits (32 bytes), this line has " +
                        std::to_string(line.size()) + " characters" + std::string(kHowToMake));
    }
    std::array<std::uint8_t, kPreSharedKeySize> bytes{};
    for (std::size_t i = 0; i < line.size(); ++i) {
      const int v = hex_value(line[i]);
      if (v < 0) {
        OPENSSL_cleanse(bytes.data(), bytes.size());
        return refuse(KeyFileError::malformed, line_number,
                      where + "character " + std::to_string(i + 1) +
                          " of the key is not a hex digit" + std::string(kHowToMake));
      }
      bytes[i / 2] = static_cast<std::uint8_t>(bytes[i / 2] << 4 | v);
    }
    if (result.keys.size() == kMaxKeysPerFile) {
      OPENSSL_cleanse(bytes.data(), bytes.size());
      return refuse(KeyFileError::too_many_keys, line_number,
                    where + "a key file holds at most " + std::to_string(kMaxKeysPerFile) +
                        " keys (the current one and, while rotating, the next); remove the "
                        "retired key");
    }
    result.keys.emplace_back(bytes);
    OPENSSL_cleanse(bytes.data(), bytes.size());
  }
  if (result.keys.empty()) {
    return refuse(KeyFileError::no_key, 0,
                  file + ": holds no key (only comments or blank lines)" + std::string(kHowToMake));
  }
  return result;
}

std::optional<KeyFileProblem> check_key_file_permissions(const struct stat& status,
                                                         uid_t process_user,
                                                         const std::string& file) {
  if (!S_ISREG(status.st_mode)) {
    return KeyFileProblem{make_error_code(KeyFileError::not_a_regular_file), 0,
                          file + ": not a regular file; a key file must be a plain file"};
  }
  if (status.st_uid != process_user && status.st_uid != 0) {
    return KeyFileProblem{make_error_code(KeyFileError::wrong_owner), 0,
                          file + ": owned by uid " + std::to_string(status.st_uid) +
                              ", but this process runs as uid " + std::to_string(process_user) +
                              "; run `chown " + std::to_string(process_user) + " " + file +
                              "` (or make root its owner)"};
  }
  if ((status.st_mode & (S_IRWXG | S_IRWXO)) != 0) {
    return KeyFileProblem{make_error_code(KeyFileError::too_open), 0,
                          file + ": mode " + octal_mode(status.st_mode) +
                              " lets group or others access the key; run `chmod 600 " + file + "`"};
  }
  return std::nullopt;
}

KeyFileResult load_key_file(const std::string& path) {
  // O_NONBLOCK: a FIFO named as the key file opens at once (and is refused as no regular file
  // below) instead of holding startup until something writes to it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) {
    const int e = errno;
    return refuse(KeyFileError::cannot_open, 0,
                  path + ": cannot open: " + std::generic_category().message(e));
  }
  struct FdCloser {
    int fd;
    ~FdCloser() { ::close(fd); }
  } closer{fd};

  struct stat status {};
  if (::fstat(fd, &status) != 0) {
    const int e = errno;
    return refuse(KeyFileError::cannot_open, 0,
                  path + ": cannot stat: " + std::generic_category().message(e));
  }
  if (auto problem = check_key_file_permissions(status, ::geteuid(), path)) {
    KeyFileResult result;
    result.problem = std::move(problem);
    return result;
  }

  std::string text(kMaxKeyFileSize + 1, '\0');
  std::size_t size = 0;
  while (size < text.size()) {
    const ssize_t n = ::read(fd, text.data() + size, text.size() - size);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int e = errno;
      OPENSSL_cleanse(text.data(), text.size());
      return refuse(KeyFileError::cannot_open, 0,
                    path + ": cannot read: " + std::generic_category().message(e));
    }
    if (n == 0) break;
    size += static_cast<std::size_t>(n);
  }
  KeyFileResult result;
  if (size > kMaxKeyFileSize) {
    result = refuse(KeyFileError::too_large, 0,
                    path + ": larger than " + std::to_string(kMaxKeyFileSize) +
                        " bytes; a key file holds one or two 64-hex-digit keys");
  } else {
    result = parse_key_file(std::string_view(text.data(), size), path);
  }
  OPENSSL_cleanse(text.data(), text.size());
  return result;
}

}  // namespace canbridge::backbone
