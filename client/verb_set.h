// VerbSet: the `clnerf` CLI's verbs, registered COLMAP-style. Each verb is a
// pair of functions beside each other in its own file:
//
//   CLI::App* BindTrain(CLI::App* parent, TrainArgs* args);  // adds `train`
//   int RunTrain(const TrainArgs& args);                      // runs it
//
// Bind adds the verb's subcommand under `parent` and binds every flag
// straight onto `args`, whose fields are the core Options structs the verb
// runs with (FitOptions, UpdateOptions, ...), so --help shows the core
// defaults and nothing copies them. VerbSet owns one Args per verb, and after
// parsing runs the verb that was chosen. Remote verbs (Args with a
// `RemoteOptions remote`) also take the remote flags given before the verb
// (`clnerf --server H:P upload DIR`); a flag after the verb wins.
//
// main() builds one; verbs are listed once, in RegisterVerbs
// (client/verbs.h). Not thread-safe.
#ifndef CLNERF_CLIENT_VERB_SET_H_
#define CLNERF_CLIENT_VERB_SET_H_

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "CLI/CLI.hpp"
#include "client/remote_commands.h"

namespace clnerf {

class VerbSet {
 public:
  // Adds the global remote flags to `app` (which must outlive the set).
  explicit VerbSet(CLI::App* app);
  VerbSet(const VerbSet&) = delete;
  VerbSet& operator=(const VerbSet&) = delete;

  CLI::App* app() const { return app_; }

  // Registers a verb under `parent` (default: the top-level app) and returns
  // its subcommand.
  template <class Args>
  CLI::App* Add(CLI::App* (*bind)(CLI::App* parent, Args* args), int (*run)(const Args& args),
                CLI::App* parent = nullptr) {
    auto args = std::make_shared<Args>();
    CLI::App* command = bind(parent != nullptr ? parent : app_, args.get());
    RemoteOptions* remote = nullptr;
    if constexpr (requires { args->remote; }) remote = &args->remote;
    verbs_.push_back({command, remote, [args, run] { return run(*args); }});
    return command;
  }

  // After app()->parse(): applies the remote flags given before the verb and
  // runs the chosen verb. Returns its exit code (1 if no verb was chosen).
  int RunChosen();

 private:
  struct Verb {
    CLI::App* command;
    RemoteOptions* remote;  // Null for local verbs.
    std::function<int()> run;
  };
  CLI::App* app_;
  RemoteOptions global_remote_;  // Remote flags given before the verb.
  std::vector<Verb> verbs_;
};

// The remote flags (--server, --token, --timeout, --tls-ca, --json, --place), bound
// onto `options`; the server and token default to $CLNERF_SERVER and
// $CLNERF_TOKEN.
void BindRemoteFlags(CLI::App* command, RemoteOptions* options);

// --threads (0 = all cores) bound onto `threads`.
CLI::Option* BindThreadsFlag(CLI::App* command, int* threads);

// An enum flag spelled by the core's own names: `--init warm|reinit` bound
// onto an InitMode through InitModeName. `values` lists the choices; any
// other word is refused with the list.
template <class Enum>
CLI::Option* BindEnumFlag(CLI::App* command, const std::string& flag, Enum* value, std::vector<Enum> values,
                          const char* (*name)(Enum), const std::string& help) {
  std::vector<std::string> names;
  for (Enum e : values) names.push_back(name(e));
  return command
      ->add_option_function<std::string>(
          flag,
          [value, values, name](const std::string& given) {
            for (Enum e : values) {
              if (given == name(e)) *value = e;
            }
          },
          help)
      ->check(CLI::IsMember(names))
      ->default_str(name(*value));
}

}  // namespace clnerf

#endif  // CLNERF_CLIENT_VERB_SET_H_
