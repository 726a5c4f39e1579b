#include "server/viewer_files.h"

#include <btfvq/error.h>
#include "pipeline/runtime/resources.h"

namespace btfvq::server {

namespace {

// Browsers refuse a JavaScript module served with another type.
std::string content_type_of(const std::string& name) {
  auto ends_with = [&](const std::string& suffix) {
    return name.size() >= suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
  };
  if (ends_with(".html")) return "text/html; charset=utf-8";
  if (ends_with(".js")) return "text/javascript; charset=utf-8";
  if (ends_with(".css")) return "text/css; charset=utf-8";
  return "application/octet-stream";
}

}  // namespace

ViewerFile viewer_page() { return viewer_file("index.html"); }

ViewerFile viewer_file(const std::string& name) {
  const auto& resources = embedded_resources();
  const auto it = resources.find("viewer/" + name);
  if (name.find('/') != std::string::npos || it == resources.end())
    throw NotFoundError("the viewer has no file '" + name + "'");
  return {it->second, content_type_of(name)};
}

}  // namespace btfvq::server
