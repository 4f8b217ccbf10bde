// ParsePrometheusText: a strict reader of the Prometheus text exposition
// format (0.0.4) for tests of GET /metrics. Thread-safe (no state).
#ifndef CLNERF_SERVER_PROMETHEUS_TEXT_TEST_UTIL_H_
#define CLNERF_SERVER_PROMETHEUS_TEXT_TEST_UTIL_H_

#include <cstdlib>
#include <map>
#include <regex>
#include <sstream>
#include <string>

#include "absl/strings/str_cat.h"

namespace clnerf::testing_util {

// A strict reader of the Prometheus text exposition format (0.0.4): every
// line is a comment (# HELP / # TYPE), blank, or a sample
// `name{label="value",...} value`, and every sample belongs to a declared
// family (histograms: _bucket, _sum, _count). Fills `samples` keyed by the
// sample line's name and labels; returns "" or what is wrong.
inline std::string ParsePrometheusText(const std::string& text, std::map<std::string, double>* samples) {
  static const std::regex kHelp(R"(# HELP [a-zA-Z_:][a-zA-Z0-9_:]* .*)");
  static const std::regex kType(R"(# TYPE ([a-zA-Z_:][a-zA-Z0-9_:]*) (counter|gauge|histogram|summary|untyped))");
  static const std::regex kSample(
      R"(([a-zA-Z_:][a-zA-Z0-9_:]*)(\{([a-zA-Z_][a-zA-Z0-9_]*="([^"\\\n]|\\[\\"n])*",?)*\})? )"
      R"(([-+]?([0-9]*\.?[0-9]+([eE][-+]?[0-9]+)?|Inf)|NaN)( -?[0-9]+)?)");
  std::map<std::string, std::string> types;
  std::istringstream in(text);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    std::smatch m;
    if (line.empty() || std::regex_match(line, kHelp)) continue;
    if (std::regex_match(line, m, kType)) {
      types[m[1]] = m[2];
      continue;
    }
    if (!std::regex_match(line, m, kSample)) return absl::StrCat("line ", n, " is not valid: '", line, "'");
    std::string family = m[1];
    for (const char* suffix : {"_bucket", "_sum", "_count"}) {
      const std::string sfx = suffix;
      if (types.count(family) == 0 && family.size() > sfx.size() &&
          family.compare(family.size() - sfx.size(), sfx.size(), sfx) == 0) {
        family = family.substr(0, family.size() - sfx.size());
      }
    }
    if (types.count(family) == 0) return absl::StrCat("line ", n, ": no # TYPE for '", family, "'");
    const size_t space = line.rfind(' ');
    (*samples)[line.substr(0, line.find(' ', line.find('}') == std::string::npos ? 0 : line.find('}')))] =
        std::strtod(line.c_str() + space + 1, nullptr);
  }
  return types.empty() ? "no metric families" : "";
}

}  // namespace clnerf::testing_util

#endif  // CLNERF_SERVER_PROMETHEUS_TEXT_TEST_UTIL_H_
