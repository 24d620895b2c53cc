#include "backbone/pre_shared_keys.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace canbridge::backbone {
namespace {

// Test keys only, made here; never a real key.
const std::string kHexA = "00112233445566778899aabbccddeeff00112233445566778899AABBCCDDEEFF";
const std::string kHexB = std::string(64, '7');

class KeyFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("canbridge_psk_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string write(const std::string& name, const std::string& text, mode_t mode) {
    const auto path = (dir_ / name).string();
    std::ofstream(path) << text;
    EXPECT_EQ(::chmod(path.c_str(), mode), 0);
    return path;
  }

  std::filesystem::path dir_;
};

TEST_F(KeyFileTest, Mode0600IsAcceptedAndParsed) {
  const auto path = write("gw1.key", "# gateway gw1\n" + kHexA + "\n", 0600);
  const KeyFileResult r = load_key_file(path);
  ASSERT_TRUE(r) << r.problem->message;
  ASSERT_EQ(r.keys.size(), 1u);
  EXPECT_EQ(r.keys[0].bytes()[0], 0x00);
  EXPECT_EQ(r.keys[0].bytes()[1], 0x11);
  EXPECT_EQ(r.keys[0].bytes()[15], 0xff);
  EXPECT_EQ(r.keys[0].bytes()[31], 0xff);
}

TEST_F(KeyFileTest, Mode0400IsAccepted) {
  EXPECT_TRUE(load_key_file(write("gw1.key", kHexA + "\n", 0400)));
}

TEST_F(KeyFileTest, GroupOrWorldReadableFilesAreRefusedNamingFileAndFix) {
  for (const mode_t mode : {0644, 0640, 0604, 0620, 0602}) {
    const auto path = write("gw1.key", kHexA + "\n", mode);
    const KeyFileResult r = load_key_file(path);
    ASSERT_FALSE(r) << std::oct << mode;
    EXPECT_TRUE(r.keys.empty());
    EXPECT_EQ(r.problem->error, KeyFileError::too_open);
    EXPECT_NE(r.problem->message.find(path), std::string::npos) << r.problem->message;
    EXPECT_NE(r.problem->message.find("chmod 600 " + path), std::string::npos)
        << r.problem->message;
  }
}

TEST_F(KeyFileTest, MissingFileAndDirectoryAreRefused) {
  EXPECT_EQ(load_key_file((dir_ / "none.key").string()).problem->error, KeyFileError::cannot_open);
  std::filesystem::create_directory(dir_ / "d");
  ::chmod((dir_ / "d").c_str(), 0700);
  EXPECT_EQ(load_key_file((dir_ / "d").string()).problem->error, KeyFileError::not_a_regular_file);
}

TEST_F(KeyFileTest, OversizeFileIsRefused) {
  const auto path = write("big.key", kHexA + "\n" + std::string(kMaxKeyFileSize, '#'), 0600);
  EXPECT_EQ(load_key_file(path).problem->error, KeyFileError::too_large);
}

TEST(KeyFilePermissions, OwnerMustBeTheProcessUserOrRoot) {
  struct stat st {};
  st.st_mode = S_IFREG | 0600;
  st.st_uid = 1000;
  EXPECT_FALSE(check_key_file_permissions(st, 1000, "k"));
  st.st_uid = 0;
  EXPECT_FALSE(check_key_file_permissions(st, 1000, "k"));
  st.st_uid = 1001;
  const auto problem = check_key_file_permissions(st, 1000, "/etc/canbridge/keys/gw1.key");
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->error, KeyFileError::wrong_owner);
  EXPECT_NE(problem->message.find("chown 1000 /etc/canbridge/keys/gw1.key"), std::string::npos)
      << problem->message;
}

TEST(KeyFileParse, CommentsBlanksAndTwoKeysForRotation) {
  const auto r = parse_key_file(
      "\n# current\n  " + kHexA + "  # since March\r\n\n" + kHexB + "\n# end\n", "k");
  ASSERT_TRUE(r) << r.problem->message;
  ASSERT_EQ(r.keys.size(), 2u);
  EXPECT_EQ(r.keys[0].bytes()[1], 0x11);
  EXPECT_EQ(r.keys[1].bytes()[0], 0x77);
}

TEST(KeyFileParse, MalformedHexIsRefusedWithLineAndWithoutQuotingTheKey) {
  std::string bad = kHexA;
  bad[10] = 'g';
  const auto r = parse_key_file("# c\n" + bad + "\n", "gw1.key");
  ASSERT_FALSE(r);
  EXPECT_EQ(r.problem->error, KeyFileError::malformed);
  EXPECT_EQ(r.problem->line, 2);
  EXPECT_NE(r.problem->message.find("gw1.key:2:"), std::string::npos) << r.problem->message;
  EXPECT_NE(r.problem->message.find("character 11"), std::string::npos) << r.problem->message;
  EXPECT_NE(r.problem->message.find("openssl rand -hex 32"), std::string::npos);
  EXPECT_EQ(r.problem->message.find(bad.substr(0, 10)), std::string::npos) << "key leaked";
}

TEST(KeyFileParse, WrongLengthsAreRefused) {
  for (const std::string& line : {kHexA.substr(1), kHexA + "0", kHexA + kHexA, std::string("x")}) {
    const auto r = parse_key_file(line + "\n", "k");
    ASSERT_FALSE(r) << line;
    EXPECT_EQ(r.problem->error, KeyFileError::malformed);
    EXPECT_NE(r.problem->message.find("64 hex digits"), std::string::npos);
  }
}

TEST(KeyFileParse, EmptyAndThreeKeysAreRefused) {
  EXPECT_EQ(parse_key_file("# nothing\n\n", "k").problem->error, KeyFileError::no_key);
  EXPECT_EQ(parse_key_file("", "k").problem->error, KeyFileError::no_key);
  const auto r = parse_key_file(kHexA + "\n" + kHexB + "\n" + kHexA + "\n", "k");
  ASSERT_FALSE(r);
  EXPECT_EQ(r.problem->error, KeyFileError::too_many_keys);
  EXPECT_EQ(r.problem->line, 3);
}

}  // namespace
}  // namespace canbridge::backbone
