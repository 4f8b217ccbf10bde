// WebAssets: the web viewer's static files (server/frontends/web/), compiled into the
// server binary at build time (server/frontends/embed_web.cmake), so an installed or
// containerised server serves its page with no extra files and nothing is
// fetched from the internet. Plain HTML/JS/CSS, no build step.
//
// Thread-safety: immutable data.
#ifndef CLNERF_SERVER_WEB_ASSETS_H_
#define CLNERF_SERVER_WEB_ASSETS_H_

#include <string_view>

namespace clnerf {

struct WebAsset {
  std::string_view path;          // URL path, e.g. "/viewer.js".
  std::string_view content_type;  // e.g. "text/javascript; charset=utf-8".
  std::string_view body;
};

// The asset served at `path` ("/" is the page), or null.
const WebAsset* FindWebAsset(std::string_view path);

}  // namespace clnerf

#endif  // CLNERF_SERVER_WEB_ASSETS_H_
