// clnerf: command-line entry point. Flags are parsed here and only here; each
// verb binds its own (client/verbs.h).
#include <string>

#include "CLI/CLI.hpp"
#include "client/verb_set.h"
#include "client/verbs.h"
#include "spdlog/sinks/stdout_color_sinks.h"
#include "spdlog/spdlog.h"

int main(int argc, char** argv) {
  CLI::App app{"clnerf: continual NeRF on CPU (CLNeRF with an Instant-NGP backbone)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "clnerf 0.1.0");
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error|off")->capture_default_str();
  clnerf::VerbSet verbs(&app);
  clnerf::RegisterVerbs(&verbs);
  CLI11_PARSE(app, argc, argv);
  // Logs go to stderr so stdout carries only results (lines and JSON).
  spdlog::set_default_logger(spdlog::stderr_color_mt("clnerf"));
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");
  return verbs.RunChosen();
}
