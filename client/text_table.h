// TextTable: left-aligned columns for the CLI's human-readable listings
// (jobs, versions). Rows are buffered and printed with each column as wide as
// its widest cell, separated by two spaces. Not thread-safe: one owner.
#ifndef CLNERF_CLIENT_TEXT_TABLE_H_
#define CLNERF_CLIENT_TEXT_TABLE_H_

#include <cstdio>
#include <string>
#include <vector>

namespace clnerf {

class TextTable {
 public:
  explicit TextTable(std::vector<std::string> header) { rows_.push_back(std::move(header)); }
  void AddRow(std::vector<std::string> row) { rows_.push_back(std::move(row)); }
  // Prints the header and every row; trailing spaces are trimmed.
  void Print(FILE* out = stdout) const;

 private:
  std::vector<std::vector<std::string>> rows_;
};

}  // namespace clnerf

#endif  // CLNERF_CLIENT_TEXT_TABLE_H_
