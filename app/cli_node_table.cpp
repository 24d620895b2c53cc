#include "app/cli_node_table.hpp"

#include <algorithm>
#include <array>
#include <ostream>
#include <string>

namespace canbridge::cli {

void print_node_table(std::ostream& out, const std::vector<NodeRow>& rows) {
  if (rows.empty()) {
    out << "no nodes\n";
    return;
  }
  struct Column {
    const char* key;
    const char* title;
  };
  static constexpr std::array<Column, 11> kColumns = {{
      {"net", "NET"},
      {"module", "MODULE"},
      {"gateway", "GATEWAY"},
      {"local", "LOCAL"},
      {"surface", "SURFACE"},
      {"profile", "PROFILE"},
      {"kind", "KIND"},
      {"state", "STATE"},
      {"hb_age_ms", "HB_AGE_MS"},
      {"boot_count", "BOOTS"},
      {"emcy", "EMCY"},
  }};
  std::array<std::size_t, kColumns.size()> width{};
  for (std::size_t c = 0; c < kColumns.size(); ++c) {
    width[c] = std::string_view(kColumns[c].title).size();
    for (const auto& row : rows) width[c] = std::max(width[c], field(row, kColumns[c].key).size());
  }
  auto print_row = [&](auto&& cell) {
    std::string line;
    for (std::size_t c = 0; c < kColumns.size(); ++c) {
      const std::string text = cell(c);
      line += text;
      if (c + 1 < kColumns.size()) line += std::string(width[c] - text.size() + 2, ' ');
    }
    out << line << "\n";
  };
  print_row([&](std::size_t c) { return std::string(kColumns[c].title); });
  for (const auto& row : rows) {
    print_row([&](std::size_t c) {
      const std::string v = field(row, kColumns[c].key);
      return v.empty() ? std::string("-") : v;
    });
  }
}

}  // namespace canbridge::cli
