#pragma once
// Reading what a request brings: JSON and upload bodies, numeric headers, and the query
// parameters of the API (docs/api.md). Each rejection is an InputError naming what was wrong.
#include <httplib.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>

#include "pipeline/decode/preview.h"
#include "server/uploads.h"

namespace btfvq::server {

// A JSON body of at most `limit` bytes (413 beyond); malformed JSON is a 400 naming the position.
nlohmann::json read_json_body(const httplib::ContentReader& reader, uint64_t limit);

// The headers of PUT /v1/uploads/{id}: Content-Length, Content-Range (a piece of a resumable
// upload; 400 when malformed) and X-Sha256.
UploadRequest upload_request(const httplib::Request& req);

// Streams an upload body into the sink that `begin` opens and finishes it; returns the upload's
// state. A request that `begin` refuses has its modest body read first, so that the client gets
// the answer (a 409 with where to continue, say) instead of a reset connection; one declared too
// large, or larger than 64 MiB, is answered at once and the connection closed. Past the sink's
// limit the rest of a modest body is still read, for the same reason, and so is the rest of a body
// that the disk refused; a huge one is cut off.
nlohmann::json receive_upload(const httplib::Request& req, const httplib::ContentReader& reader,
                              httplib::Response& res, const std::function<std::unique_ptr<UploadSink>()>& begin);

std::optional<uint64_t> header_number(const httplib::Request& req, const char* name);

// ?version=N of a download; nothing when absent.
std::optional<int64_t> version_query(const httplib::Request& req);

// The query of a preview: scene=sphere|plane, light=T,P (camera frame, degrees), env=1, size=N.
PreviewOptions preview_query(const httplib::Request& req);

}  // namespace btfvq::server
