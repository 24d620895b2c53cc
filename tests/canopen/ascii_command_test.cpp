// CiA 309-3 command lines: the standard commands as CANopenNode's gateway reads them, canbridge's
// extensions, the response lines, and any bad input answered with a 309-3 error, never a crash.
#include "canopen/ascii_command.hpp"

#include <gtest/gtest.h>

#include <random>
#include <string>

#include "canopen/ascii_response.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::canopen {
namespace {

AsciiCommand ok(std::string_view line) {
  const AsciiParse parse = parse_ascii_command(line);
  EXPECT_TRUE(parse.ok()) << line << ": " << parse.detail;
  return parse.command;
}

AsciiParse bad(std::string_view line, AsciiError expected = AsciiError::syntax) {
  AsciiParse parse = parse_ascii_command(line);
  EXPECT_FALSE(parse.ok()) << line;
  if (parse.error) {
    EXPECT_EQ(static_cast<int>(*parse.error), static_cast<int>(expected)) << line;
  }
  EXPECT_FALSE(parse.detail.empty()) << line;
  return parse;
}

TEST(AsciiCommand, ReadWithSequenceNetNodeAndType) {
  const auto cmd = ok("[12] 3 5 read 0x1018 2 u32");
  EXPECT_EQ(cmd.verb, AsciiVerb::read);
  EXPECT_EQ(cmd.sequence, 12u);
  EXPECT_EQ(cmd.net, 3u);
  EXPECT_EQ(cmd.node, 5u);
  EXPECT_EQ(cmd.index, 0x1018);
  EXPECT_EQ(cmd.sub, 2);
  EXPECT_EQ(cmd.type, AsciiType::u32);
}

TEST(AsciiCommand, ReadShortFormsAndDefaults) {
  const auto cmd = ok("r 0x1000 0");
  EXPECT_EQ(cmd.verb, AsciiVerb::read);
  EXPECT_FALSE(cmd.sequence);
  EXPECT_FALSE(cmd.net);
  EXPECT_FALSE(cmd.node);
  EXPECT_FALSE(cmd.type);                             // hex
  const auto node_only = ok("[1] 7 R 4096 0 X32\r");  // case does not matter, CR ignored
  EXPECT_EQ(node_only.node, 7u);
  EXPECT_FALSE(node_only.net);
  EXPECT_EQ(node_only.index, 0x1000);
  EXPECT_EQ(node_only.type, AsciiType::x32);
}

TEST(AsciiCommand, WriteParsesItsValue) {
  const auto cmd = ok("[2] 4 w 0x2000 1 u16 0x1234");
  EXPECT_EQ(cmd.verb, AsciiVerb::write);
  EXPECT_EQ(cmd.value, (std::vector<std::uint8_t>{0x34, 0x12}));
  const auto text = ok("4 write 0x2001 0 vs \"a # b\"  # the comment");
  EXPECT_EQ(text.value, (std::vector<std::uint8_t>{'a', ' ', '#', ' ', 'b'}));
  const auto hex = ok("4 write 0x2001 0 hex 01 02 03");
  EXPECT_EQ(hex.value, (std::vector<std::uint8_t>{1, 2, 3}));
}

TEST(AsciiCommand, WriteErrorsSayWhat) {
  EXPECT_NE(bad("4 w 0x2000 1").detail.find("missing datatype"), std::string::npos);
  EXPECT_NE(bad("4 w 0x2000 1 u16").detail.find("missing value"), std::string::npos);
  EXPECT_NE(bad("4 w 0x2000 1 u24 5").detail.find("unknown datatype"), std::string::npos);
  EXPECT_NE(bad("4 w 0x2000 1 u8 256").detail.find("out of range"), std::string::npos);
  EXPECT_NE(bad("4 w 0x12345 1 u8 1").detail.find("index"), std::string::npos);
  EXPECT_NE(bad("4 w 0x1000 256 u8 1").detail.find("subindex"), std::string::npos);
  EXPECT_NE(bad("4 w zz 0 u8 1").detail.find("not a number"), std::string::npos);
}

TEST(AsciiCommand, SequenceIsKeptWhenTheRestFails) {
  const auto parse = bad("[77] 4 r 0x1000");
  EXPECT_EQ(parse.command.sequence, 77u);
  bad("[x] 4 r 0x1000 0");
  bad("[4294967296] r 0x1000 0");
  bad("[] r 0x1000 0");
  bad("[5]");
}

TEST(AsciiCommand, NetAndNodeLimits) {
  bad("128 r 0x1000 0", AsciiError::unsupported_node);
  bad("65536 1 r 0x1000 0", AsciiError::unsupported_net);
  bad("1 2 3 r 0x1000 0");
  bad("5");
}

TEST(AsciiCommand, Nmt) {
  EXPECT_EQ(ok("5 start").nmt, AsciiNmt::start);
  EXPECT_EQ(ok("5 stop").nmt, AsciiNmt::stop);
  EXPECT_EQ(ok("5 preop").nmt, AsciiNmt::preoperational);
  EXPECT_EQ(ok("5 preoperational").nmt, AsciiNmt::preoperational);
  EXPECT_EQ(ok("5 reset node").nmt, AsciiNmt::reset_node);
  EXPECT_EQ(ok("5 reset comm").nmt, AsciiNmt::reset_communication);
  EXPECT_EQ(ok("0 reset communication").node, 0u);  // every node
  EXPECT_EQ(ok("start").verb, AsciiVerb::nmt);
  bad("5 reset");
  bad("5 reset everything");
  bad("5 start now");
}

TEST(AsciiCommand, SetCommands) {
  auto cmd = ok("set network 2");
  EXPECT_EQ(cmd.verb, AsciiVerb::set_network);
  EXPECT_EQ(cmd.number, 2u);
  cmd = ok("2 set node 9");  // a single number before a network command is the net
  EXPECT_EQ(cmd.verb, AsciiVerb::set_node);
  EXPECT_EQ(cmd.net, 2u);
  EXPECT_FALSE(cmd.node);
  EXPECT_EQ(ok("set sdo_timeout 500").number, 500u);
  EXPECT_EQ(ok("set sdo_block 1").verb, AsciiVerb::set_sdo_block);
  cmd = ok("[3] 2 9 set node_id 12");
  EXPECT_EQ(cmd.verb, AsciiVerb::set_node_id);
  EXPECT_EQ(cmd.net, 2u);
  EXPECT_EQ(cmd.node, 9u);
  EXPECT_EQ(cmd.number, 12u);
  bad("set node 0");
  bad("set node 128");
  bad("set sdo_timeout 0");
  bad("set sdo_block 2");
  bad("1 2 set node 3");
  bad("set");
  bad("5 set node_id 128");
  bad("set bitrate 5", AsciiError::request_not_supported);
}

TEST(AsciiCommand, Extensions) {
  auto cmd = ok("[1] auth 0123abcd");
  EXPECT_EQ(cmd.verb, AsciiVerb::auth);
  EXPECT_EQ(cmd.text, "0123abcd");
  bad("auth");
  bad("auth a b");
  bad("auth " + std::string(5000, 'a'));
  cmd = ok("[2] 3 nodes");
  EXPECT_EQ(cmd.verb, AsciiVerb::nodes);
  EXPECT_EQ(cmd.net, 3u);
  cmd = ok("[3] 2 5 flash /tmp/fw image.bin");
  EXPECT_EQ(cmd.verb, AsciiVerb::flash);
  EXPECT_EQ(cmd.node, 5u);
  EXPECT_EQ(cmd.text, "/tmp/fw image.bin");
  bad("5 flash");
  cmd = ok("monitor");
  EXPECT_EQ(cmd.verb, AsciiVerb::monitor);
  EXPECT_FALSE(cmd.module);
  EXPECT_EQ(ok("monitor module=2").module, 2u);
  bad("monitor module=x");
  bad("monitor node=2");
  bad("3 monitor");
}

TEST(AsciiCommand, Lss) {
  auto cmd = ok("[4] 2 lss_switch_sel 1 2 3 0x10");
  EXPECT_EQ(cmd.verb, AsciiVerb::lss);
  EXPECT_EQ(cmd.text, "lss_switch_sel");
  EXPECT_EQ(cmd.net, 2u);
  EXPECT_EQ(cmd.args, (std::vector<std::uint32_t>{1, 2, 3, 16}));
  EXPECT_EQ(ok("lss_switch_glob 1").args, (std::vector<std::uint32_t>{1}));
  EXPECT_EQ(ok("lss_set_node 255").args, (std::vector<std::uint32_t>{255}));
  EXPECT_TRUE(ok("lss_inquire_addr").args.empty());
  EXPECT_EQ(ok("lss_inquire_addr 3").args, (std::vector<std::uint32_t>{3}));
  EXPECT_EQ(ok("lss_store").verb, AsciiVerb::lss);
  EXPECT_EQ(ok("lss_get_node").verb, AsciiVerb::lss);
  bad("lss_switch_glob 2");
  bad("lss_switch_sel 1 2 3");
  bad("lss_set_node 128");
  bad("lss_inquire_addr 4");
  bad("lss_store now");
  bad("lss_conf_bitrate 0 2", AsciiError::request_not_supported);
}

TEST(AsciiCommand, HelpAndUnknown) {
  EXPECT_EQ(ok("help").verb, AsciiVerb::help);
  EXPECT_EQ(ok("help datatype").text, "datatype");
  EXPECT_EQ(ok("help LSS").text, "lss");
  bad("help me");
  bad("frobnicate", AsciiError::request_not_supported);
  EXPECT_FALSE(ascii_help("").empty());
  EXPECT_FALSE(ascii_help("datatype").empty());
  EXPECT_FALSE(ascii_help("lss").empty());
}

TEST(AsciiCommand, BlankAndCommentLinesAreNothing) {
  EXPECT_EQ(ok("").verb, AsciiVerb::none);
  EXPECT_EQ(ok("   \t ").verb, AsciiVerb::none);
  EXPECT_EQ(ok("# just a comment").verb, AsciiVerb::none);
  EXPECT_EQ(ok("\r").verb, AsciiVerb::none);
  EXPECT_EQ(ok("5 start # go").verb, AsciiVerb::nmt);
}

TEST(AsciiCommand, GarbageIsASyntaxErrorNeverACrash) {
  bad(std::string("5 r 0x1000\0 0", 13));
  EXPECT_NE(bad(std::string("\x01\x02", 2)).detail.find("control byte 0x01"), std::string::npos);
  bad("\x7f");
  bad(std::string(100, '9') + " r 0x1000 0");
  bad("r " + std::string(100, '1') + " 0");
  bad(std::string(100, 'r'), AsciiError::syntax);
  std::mt19937 random(16);
  for (int i = 0; i < 20000; ++i) {
    std::string line(random() % 40, '\0');
    for (char& c : line) c = static_cast<char>(random() % 256);
    (void)parse_ascii_command(line);  // any outcome; sanitizers watch the rest
  }
  // Printable garbage built from the command's own words.
  const char* words[] = {"[1]",     "5",       "r",     "w",    "0x1000", "u8",
                         "vs",      "\"",      "#",     "set",  "node",   "lss_switch_sel",
                         "monitor", "module=", "flash", "auth", "reset",  "-1"};
  for (int i = 0; i < 20000; ++i) {
    std::string line;
    for (unsigned n = random() % 8; n > 0; --n) line += std::string(words[random() % 18]) + " ";
    (void)parse_ascii_command(line);
  }
}

TEST(AsciiResponse, Lines) {
  EXPECT_EQ(ascii_ok(7u), "[7] OK\r\n");
  EXPECT_EQ(ascii_ok(std::nullopt), "OK\r\n");
  EXPECT_EQ(ascii_line(1u, "4660"), "[1] 4660\r\n");
  EXPECT_EQ(ascii_error(3u, AsciiError::syntax), "[3] ERROR:101 #Syntax error.\r\n");
  EXPECT_EQ(ascii_error(std::nullopt, AsciiError::not_permitted),
            "ERROR:403 #Not permitted for role monitor.\r\n");
  EXPECT_EQ(ascii_error(std::nullopt, AsciiError::authentication_required),
            "ERROR:401 #Authentication required.\r\n");
  EXPECT_EQ(ascii_error(2u, AsciiError::syntax, "bad\r\nline"),
            "[2] ERROR:101 #Syntax error. bad  line\r\n");
  EXPECT_EQ(ascii_sdo_abort(9u, 0x06020000), "[9] ERROR:0x06020000 #Object does not exist.\r\n");
  // canbridge's detail follows the standard text inside the comment, never before it.
  EXPECT_EQ(ascii_sdo_abort(std::nullopt, 0x08000020, "verify"),
            "ERROR:0x08000020 #Data cannot be transferred or stored to application. verify\r\n");
}

}  // namespace
}  // namespace canbridge::canopen
