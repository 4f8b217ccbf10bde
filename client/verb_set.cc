#include "client/verb_set.h"

#include <cstdlib>

namespace clnerf {

VerbSet::VerbSet(CLI::App* app) : app_(app) { BindRemoteFlags(app_, &global_remote_); }

int VerbSet::RunChosen() {
  for (Verb& verb : verbs_) {
    if (!*verb.command) continue;
    if (verb.remote != nullptr) {
      const auto before = [&](const char* flag) { return app_->count(flag) > 0 && verb.command->count(flag) == 0; };
      if (before("--server")) verb.remote->server = global_remote_.server;
      if (before("--token")) verb.remote->token = global_remote_.token;
      if (before("--timeout")) verb.remote->timeout_seconds = global_remote_.timeout_seconds;
      if (before("--tls-ca")) verb.remote->tls_ca = global_remote_.tls_ca;
      if (before("--json")) verb.remote->json = true;
      if (before("--place")) verb.remote->place = global_remote_.place;
    }
    return verb.run();
  }
  return 1;
}

void BindRemoteFlags(CLI::App* c, RemoteOptions* o) {
  o->server = DefaultServer();
  o->token = DefaultToken();
  c->add_option("--server", o->server, "Server HOST:PORT (env CLNERF_SERVER)")->capture_default_str();
  c->add_option("--token", o->token, "Bearer token for uploads, cancels and rollbacks (env CLNERF_TOKEN)");
  c->add_option("--timeout", o->timeout_seconds,
                "Deadline per RPC in seconds (default: 30 for calls, 600 for a render, none for streams)");
  c->add_option("--tls-ca", o->tls_ca, "PEM root certificate: connect with TLS");
  c->add_flag("--json", o->json, "Machine-readable JSON on stdout");
  if (const char* p = std::getenv("CLNERF_PLACE")) o->place = p;
  c->add_option("--place", o->place, "The place (default: \"default\"; env CLNERF_PLACE)");
}

CLI::Option* BindThreadsFlag(CLI::App* c, int* threads) {
  return c->add_option("--threads", *threads, "Threads (0 = all cores)")->capture_default_str();
}

}  // namespace clnerf
