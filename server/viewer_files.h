#pragma once
// The browser viewer's static files (viewer/*.html, *.js, *.css; docs/viewer.md), embedded in the
// binary at build time (cmake/embed_resources.cmake): the server needs no files of its own to serve
// it, and the page makes no request outside this server.
#include <string>

namespace btfvq::server {

struct ViewerFile {
  const std::string& body;
  std::string content_type;
};

// The page that shows the listing (/viewer/) and every material (/viewer/{db}/{material}): one
// HTML file whose script reads the path.
ViewerFile viewer_page();
// viewer/NAME; throws NotFoundError for a name that is not one of the viewer's files.
ViewerFile viewer_file(const std::string& name);

}  // namespace btfvq::server
