#include "client/http_client.h"

#include <httplib.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <thread>

#include "client/cli.h"
#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/sha256.h"

namespace btfvq::cli {
namespace fs = std::filesystem;
using nlohmann::json;

Remote remote_from(const Args& args) {
  Remote r;
  if (auto s = args.get("server")) r.url = *s;
  else if (const char* e = std::getenv("BTFVQ_SERVER"); e && *e) r.url = e;
  else throw InputError("no server: pass --server URL or set BTFVQ_SERVER");
  if (r.url.find("://") == std::string::npos) r.url = "http://" + r.url;
  while (!r.url.empty() && r.url.back() == '/') r.url.pop_back();
  if (auto t = args.get("token")) r.token = *t;
  else if (const char* e = std::getenv("BTFVQ_TOKEN"); e && *e) r.token = e;
  return r;
}

std::vector<Option> remote_options(std::vector<Option> own) {
  own.insert(own.begin(), {{"server", "URL", "the btfvq server (default: BTFVQ_SERVER)"},
                           {"token", "TOKEN", "its bearer token (default: BTFVQ_TOKEN)"}});
  return own;
}

void throw_http_error(int status, const std::string& body) {
  std::string code = "http_" + std::to_string(status), message = body;
  try {
    const json j = json::parse(body);
    code = j.at("error").at("code");
    message = j.at("error").at("message");
  } catch (const std::exception&) {
  }
  message = "server answered " + std::to_string(status) + ": " + message;
  if (status == 404) throw NotFoundError(message);
  if (status == 400 || status == 413 || status == 416) throw InputError(message, code);
  throw Error(code, message);
}

std::string describe_progress(const json& job) {
  std::string s = job.value("stage", "");
  if (job.value("phase", 0) > 0) s = "phase " + std::to_string(job.value("phase", 0)) + " (" + s + ")";
  if (const std::string m = job.value("material", ""); !m.empty()) s = m + ": " + s;
  if (job.value("texels_total", uint64_t(0)) > 0)
    s += " " + std::to_string(job.value("texels_done", uint64_t(0))) + "/" +
         std::to_string(job.value("texels_total", uint64_t(0))) + " texels";
  if (job.contains("codebook_sizes") && job["codebook_sizes"].value("P4", uint64_t(0)) > 0)
    s += ", P4 " + std::to_string(job["codebook_sizes"].value("P4", uint64_t(0)));
  if (job.contains("eta_s") && job["eta_s"].is_number()) s += ", ETA " + std::to_string(int(job["eta_s"].get<double>())) + " s";
  return s;
}

namespace {

json parse_reply(const httplib::Result& r, const std::string& what) {
  if (!r) throw Error("connection", "cannot reach the server for " + what + ": " + httplib::to_string(r.error()));
  if (r->status >= 400) throw_http_error(r->status, r->body);
  try {
    return r->body.empty() ? json::object() : json::parse(r->body);
  } catch (const json::exception& e) {
    throw Error("protocol", what + ": the server's reply is not JSON: " + e.what());
  }
}

uint64_t header_number(const httplib::Response& r, const char* name) {
  const std::string v = r.get_header_value(name);
  try {
    return v.empty() ? 0 : std::stoull(v);
  } catch (const std::exception&) {
    throw Error("protocol", std::string("the server sent a bad ") + name + " header: '" + v + "'");
  }
}

}  // namespace

HttpClient::HttpClient(Remote remote) : client_(std::make_unique<httplib::Client>(remote.url)), remote_(remote) {
  if (!client_->is_valid()) throw InputError("server URL '" + remote.url + "' is not valid");
  client_->set_connection_timeout(10);
  client_->set_read_timeout(60);
  client_->set_write_timeout(60);
  if (!remote.token.empty()) client_->set_bearer_token_auth(remote.token);
}

HttpClient::~HttpClient() = default;

json HttpClient::get_json(const std::string& path) { return parse_reply(client_->Get(path), "GET " + path); }

json HttpClient::post_json(const std::string& path, const json& body) {
  return parse_reply(client_->Post(path, body.dump(), "application/json"), "POST " + path);
}

json HttpClient::delete_json(const std::string& path) { return parse_reply(client_->Delete(path), "DELETE " + path); }

json HttpClient::put_file(const std::string& path, const std::string& file, const std::string& sha256,
                          const ByteProgress& progress) {
  auto in = std::make_shared<std::ifstream>(file, std::ios::binary);
  if (!*in) throw InputError("cannot read '" + file + "'");
  const uint64_t size = fs::file_size(file);
  httplib::Headers headers{{"X-Sha256", sha256}};
  auto provider = [in, size, &progress](size_t offset, size_t length, httplib::DataSink& sink) {
    std::vector<char> buffer(std::min<size_t>(length, 1 << 16));
    in->seekg(std::streamoff(offset));
    in->read(buffer.data(), std::streamsize(buffer.size()));
    const size_t got = size_t(in->gcount());
    if (got == 0) return false;
    if (progress) progress(offset + got, size);
    return sink.write(buffer.data(), got);
  };
  return parse_reply(client_->Put(path, headers, size_t(size), provider, "application/octet-stream"), "PUT " + path);
}

UploadResult HttpClient::upload_file(const std::string& id, const std::string& file, const std::string& sha256,
                                     const ByteProgress& progress, const UploadOptions& options) {
  const std::string path = "/v1/uploads/" + id;
  UploadResult result;
  std::error_code ec;
  const uint64_t size = fs::file_size(file, ec);
  if (ec) throw InputError("cannot read '" + file + "': " + ec.message());
  if (size == 0) {  // Content-Range cannot name a piece of nothing
    result.record = put_file(path, file, sha256, progress);
    result.existed = false;
    return result;
  }
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError("cannot read '" + file + "'");

  std::optional<uint64_t> offset;  // where the next piece starts; unknown: ask the server
  int failures = 0, corrections = 0;
  bool asked = false;
  // After a network error or a 5xx: a pause that grows, then the server is asked where it got to.
  auto retry_after = [&](const std::string& why) {
    if (failures >= options.max_retries)
      throw Error("connection", "upload of '" + file + "' failed " + std::to_string(failures + 1) +
                                    " times in a row, the last time: " + why +
                                    "; run the same command again to resume");
    const auto pause = std::min(options.max_pause, options.first_pause * (int64_t(1) << std::min(failures, 20)));
    ++failures;
    ++result.retries;
    std::this_thread::sleep_for(pause);
    offset.reset();
  };
  auto answer = [](const httplib::Result& r) {
    return r ? "the server answered " + std::to_string(r->status) + ": " + r->body : httplib::to_string(r.error());
  };
  for (;;) {
    if (!offset) {
      auto r = client_->Get(path);
      if (!r || r->status >= 500) {
        retry_after(answer(r));
        continue;
      }
      offset = 0;
      if (r->status != 404) {
        const json u = parse_reply(r, "GET " + path);
        const std::string state = u.value("state", "");
        if (state == "complete") {
          if (u.value("sha256", "") != sha256)
            throw Error("conflict", "upload '" + id + "' on the server hashes to " + u.value("sha256", "") +
                                        ", not to " + sha256 + " as '" + file + "'");
          result.record = u;
          result.existed = !asked;
          if (progress) progress(size, size);
          return result;
        }
        if (state == "partial" && u.value("total", uint64_t(0)) == size && u.value("sha256", "") == sha256)
          offset = std::min(u.value("received", uint64_t(0)), size);
      }
      if (!asked) result.resumed_from = *offset;
      asked = true;
      if (*offset == size) {  // every byte is there and the last piece is being checked: ask again soon
        retry_after("the server is still checking the last piece");
        continue;
      }
    }
    const uint64_t first = *offset, length = std::min(options.piece_bytes, size - first);
    const httplib::Headers headers{
        {"Content-Range", "bytes " + std::to_string(first) + "-" + std::to_string(first + length - 1) + "/" +
                              std::to_string(size)},
        {"X-Sha256", sha256}};
    uint64_t sent = 0;
    auto provider = [&](size_t at, size_t n, httplib::DataSink& sink) {
      std::vector<char> buffer(std::min<size_t>(n, 1 << 16));
      in.clear();
      in.seekg(std::streamoff(first + at));
      in.read(buffer.data(), std::streamsize(buffer.size()));
      const size_t got = size_t(in.gcount());
      if (got == 0) return false;
      sent += got;
      if (progress) progress(first + at + got, size);
      return sink.write(buffer.data(), got);
    };
    auto r = client_->Put(path, headers, size_t(length), provider, "application/octet-stream");
    result.bytes_sent += sent;
    if (!r || r->status >= 500) {
      retry_after(answer(r));
      continue;
    }
    if (r->status == 409) {
      json error;
      try {
        error = json::parse(r->body).at("error");
      } catch (const std::exception&) {
      }
      const std::string code = error.is_object() ? error.value("code", "") : "";
      if (code == "upload_offset" && error.contains("received") && ++corrections <= options.max_retries) {
        offset = std::min(error["received"].get<uint64_t>(), size);
        if (*offset < size) continue;
      }
      if (code == "conflict") {  // most likely the server still reads the piece of a connection that broke
        retry_after(answer(r));
        continue;
      }
    }
    const json reply = parse_reply(r, "PUT " + path);
    failures = corrections = 0;
    if (reply.value("state", "") == "complete") {
      result.record = reply;
      return result;
    }
    offset = reply.value("received", first + length);
  }
}

void HttpClient::events(const std::string& path,
                        const std::function<bool(const std::string&, const json&)>& on_event) {
  std::string buffer, error_body, event = "message", data;
  int status = 0;
  bool stopped = false;
  auto on_response = [&](const httplib::Response& r) {
    status = r.status;
    return true;
  };
  auto on_data = [&](const char* p, size_t n) {
    if (status >= 400) {
      error_body.append(p, n);
      return true;
    }
    buffer.append(p, n);
    size_t eol;
    while ((eol = buffer.find('\n')) != std::string::npos) {
      std::string line = buffer.substr(0, eol);
      buffer.erase(0, eol + 1);
      if (!line.empty() && line.back() == '\r') line.pop_back();
      if (line.empty()) {  // end of one event
        if (!data.empty()) {
          json j;
          try {
            j = json::parse(data);
          } catch (const json::exception&) {
            j = data;
          }
          if (!on_event(event, j)) {
            stopped = true;
            return false;
          }
        }
        event = "message";
        data.clear();
      } else if (line.rfind("event:", 0) == 0) {
        event = line.substr(line.find_first_not_of(' ', 6));
      } else if (line.rfind("data:", 0) == 0) {
        data += line.substr(std::min(line.size(), line.find_first_not_of(' ', 5)));
      }  // ":" comments are keep-alives
    }
    return true;
  };
  auto r = client_->Get(path, httplib::Headers{{"Accept", "text/event-stream"}}, on_response, on_data);
  if (stopped) return;
  if (status >= 400) throw_http_error(status, error_body);
  if (!r) throw Error("connection", "event stream " + path + " ended: " + httplib::to_string(r.error()));
}

DownloadResult HttpClient::fetch(const std::string& name, const std::string& out, std::optional<int64_t> version,
                                 const ByteProgress& progress) {
  const std::string part = out + ".part", meta_path = out + ".part.json";
  DownloadResult result;
  // A partial file is only resumable together with the record of which version it is.
  json meta;
  if (fs::exists(part) && fs::exists(meta_path)) {
    try {
      std::ifstream m(meta_path);
      meta = json::parse(m);
      if (meta.value("database", "") != name || (version && meta.value("version", int64_t(0)) != *version)) meta = json();
    } catch (const std::exception&) {
      meta = json();
    }
  }
  uint64_t offset = 0;
  if (meta.is_object() && meta.contains("version")) {
    offset = fs::file_size(part);
    version = meta["version"].get<int64_t>();
    if (offset > meta.value("size", uint64_t(0))) offset = 0;
  }
  std::string path = "/v1/databases/" + name + "/content";
  if (version) path += "?version=" + std::to_string(*version);
  httplib::Headers headers;
  if (offset > 0) headers.emplace("Range", "bytes=" + std::to_string(offset) + "-");

  std::ofstream file;
  std::string error_body;
  int status = 0;
  uint64_t total = 0, received = 0;
  auto on_response = [&](const httplib::Response& r) {
    status = r.status;
    if (status >= 400) return true;
    result.sha256 = r.get_header_value("X-Content-Sha256");
    result.version = int64_t(header_number(r, "X-Database-Version"));
    if (status == 206) {
      total = offset + header_number(r, "Content-Length");
      file.open(part, std::ios::binary | std::ios::app);
      result.resumed_from = offset;
    } else {
      offset = 0;
      total = header_number(r, "Content-Length");
      file.open(part, std::ios::binary | std::ios::trunc);
      std::ofstream m(meta_path, std::ios::trunc);
      m << json{{"database", name}, {"version", result.version}, {"sha256", result.sha256}, {"size", total}}.dump();
    }
    return bool(file);
  };
  auto on_data = [&](const char* p, size_t n) {
    if (status >= 400) {
      error_body.append(p, n);
      return true;
    }
    file.write(p, std::streamsize(n));
    received += n;
    if (progress) progress(offset + received, total);
    return bool(file);
  };
  auto r = client_->Get(path, headers, on_response, on_data);
  file.close();
  if (status == 416) {  // the partial file is not a prefix of this version: start over
    fs::remove(part);
    fs::remove(meta_path);
    throw CorruptError("the partial download does not fit the server's file");
  }
  if (status >= 400) throw_http_error(status, error_body);
  if (!r) throw Error("connection", "download interrupted (" + httplib::to_string(r.error()) +
                                        "); run the same command again to resume");
  result.size = fs::file_size(part);
  const std::string actual = sha256_file(part);
  if (result.sha256.empty() || actual != result.sha256) {
    fs::remove(part);
    fs::remove(meta_path);
    throw CorruptError("downloaded '" + name + "' hashes to " + actual + ", the server says " + result.sha256);
  }
  publish_file(part, out);  // the verified partial file becomes the download, durably
  fs::remove(meta_path);
  return result;
}

DownloadResult HttpClient::download_database(const std::string& name, const std::string& out,
                                             std::optional<int64_t> version, const ByteProgress& progress) {
  const bool resuming = fs::exists(out + ".part") && fs::exists(out + ".part.json");
  try {
    return fetch(name, out, version, progress);
  } catch (const CorruptError&) {
    if (!resuming) throw;
    return fetch(name, out, version, progress);  // the partial file was bad; it is gone now
  }
}

}  // namespace btfvq::cli
