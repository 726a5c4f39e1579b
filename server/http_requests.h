#pragma once
// Reading what a request brings: JSON and upload bodies, numeric headers, and the query
// parameters of the API (docs/api.md). Each rejection is an InputError naming what was wrong.
#include <httplib.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>

#include "pipeline/decode/preview.h"
#include "server/uploads.h"

namespace btfvq::server {

// A JSON body of at most `limit` bytes (413 beyond); malformed JSON is a 400 naming the position.
nlohmann::json read_json_body(const httplib::ContentReader& reader, uint64_t limit);

// Streams an upload body into `sink` and finishes it with the request's X-Sha256 (if any); returns
// the upload's record. Past the sink's limit the rest of a modest body is still read, so that the
// client gets the 413 instead of a reset connection; a huge one is cut off.
nlohmann::json receive_upload(const httplib::Request& req, const httplib::ContentReader& reader,
                              httplib::Response& res, UploadSink& sink);

std::optional<uint64_t> header_number(const httplib::Request& req, const char* name);

// ?version=N of a download; nothing when absent.
std::optional<int64_t> version_query(const httplib::Request& req);

// The query of a preview: scene=sphere|plane, light=T,P (camera frame, degrees), env=1, size=N.
PreviewOptions preview_query(const httplib::Request& req);

}  // namespace btfvq::server
