#include "client/http_client.h"

#include <httplib.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

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
  result.transferred = received;
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

namespace {

// The sha256 of bytes [first, last) of a file.
std::string sha256_range(const std::string& path, uint64_t first, uint64_t last) {
  std::ifstream in(path, std::ios::binary);
  in.seekg(std::streamoff(first));
  Sha256 sha;
  std::vector<char> buffer(1 << 16);
  for (uint64_t at = first; at < last;) {
    const size_t n = size_t(std::min<uint64_t>(buffer.size(), last - at));
    if (!in.read(buffer.data(), std::streamsize(n))) throw Error("io", "cannot read '" + path + "'");
    sha.update(buffer.data(), n);
    at += n;
  }
  return sha.hex();
}

}  // namespace

DownloadResult HttpClient::delta(const std::string& name, const std::string& out, std::optional<int64_t> version,
                                 const ByteProgress& progress) {
  const json info = get_json("/v1/databases/" + name);
  const std::string local = sha256_file(out);
  const json *have = nullptr, *want = version ? nullptr : &info.at("newest");
  for (const auto& v : info.at("versions")) {
    if (v.at("sha256") == local) have = &v;
    if (version && v.at("version") == *version) want = &v;
  }
  if (!want) throw NotFoundError("database '" + name + "' has no version " + std::to_string(*version));
  if (!have) throw CorruptError("the local file is no version of '" + name + "' that the server lists");
  DownloadResult result;
  result.version = want->at("version").get<int64_t>();
  result.sha256 = want->at("sha256").get<std::string>();
  result.size = want->at("size").get<uint64_t>();
  result.delta_from = have->at("version").get<int64_t>();
  if (result.delta_from == result.version) return result;  // up to date: nothing to fetch
  if (result.delta_from > result.version) throw Error("delta", "the local file is a newer version");
  const json &lh = have->at("layout"), &lw = want->at("layout");
  if (!lh.is_object() || !lw.is_object()) throw Error("delta", "the server advertises no layout of these versions");
  const uint64_t have_head = lh.at("head_length"), have_size = have->at("size"), want_head = lw.at("head_length");
  const json& prefix = lw.at("prefixes").at(size_t(result.delta_from - 1));
  const uint64_t end = prefix.at("end");
  if (prefix.at("version") != result.delta_from || end < want_head || have_head > have_size ||
      end - want_head != have_size - have_head || end > result.size)
    throw Error("delta", "the layouts of versions " + std::to_string(result.delta_from) + " and " +
                             std::to_string(result.version) + " do not share the sections");
  // The local sections must be the bytes that the new version keeps before any of them is reused.
  if (sha256_range(out, have_head, have_size) != prefix.at("sha256").get<std::string>())
    throw CorruptError("the local sections differ from those of version " + std::to_string(result.delta_from));

  AtomicFile file(out);
  std::ofstream dst(file.temp_path(), std::ios::binary | std::ios::trunc);
  Sha256 whole;
  const uint64_t to_fetch = want_head + (result.size - end);
  const std::string path = "/v1/databases/" + name + "/content?version=" + std::to_string(result.version);
  auto append = [&](const char* p, size_t n) {
    dst.write(p, std::streamsize(n));
    whole.update(p, n);
    return bool(dst);
  };
  auto fetch_range = [&](uint64_t first, uint64_t last) {  // bytes [first, last)
    int status = 0;
    std::string error_body, sha;
    auto on_response = [&](const httplib::Response& r) {
      status = r.status;
      sha = r.get_header_value("X-Content-Sha256");
      return true;
    };
    auto on_data = [&](const char* p, size_t n) {
      if (status != 206) {
        error_body.append(p, std::min<size_t>(n, 4096));
        return error_body.size() < 4096;
      }
      result.transferred += n;
      if (progress) progress(result.transferred, to_fetch);
      return append(p, n);
    };
    const auto r = client_->Get(path, {{"Range", "bytes=" + std::to_string(first) + "-" + std::to_string(last - 1)}},
                                on_response, on_data);
    if (!r) throw Error("connection", "download interrupted (" + httplib::to_string(r.error()) + ")");
    if (status != 206) throw Error("delta", "a range request answered " + std::to_string(status) + ": " + error_body);
    if (sha != result.sha256) throw Error("delta", "the server's version " + std::to_string(result.version) + " changed");
  };
  fetch_range(0, want_head);
  {
    std::ifstream src(out, std::ios::binary);
    src.seekg(std::streamoff(have_head));
    std::vector<char> buffer(1 << 16);
    for (uint64_t at = have_head; at < have_size;) {
      const size_t n = size_t(std::min<uint64_t>(buffer.size(), have_size - at));
      if (!src.read(buffer.data(), std::streamsize(n)) || !append(buffer.data(), n))
        throw Error("io", "cannot copy the local sections of '" + out + "'");
      at += n;
    }
  }
  if (end < result.size) fetch_range(end, result.size);
  dst.close();
  if (!dst) throw Error("io", "cannot write '" + file.temp_path() + "'");
  const std::string actual = whole.hex();
  if (actual != result.sha256)
    throw CorruptError("the delta of '" + name + "' hashes to " + actual + ", the server says " + result.sha256);
  file.commit();
  return result;
}

DownloadResult HttpClient::download_database(const std::string& name, const std::string& out,
                                             std::optional<int64_t> version, const ByteProgress& progress) {
  const bool resuming = fs::exists(out + ".part") && fs::exists(out + ".part.json");
  std::string fallback;
  if (!resuming && fs::is_regular_file(out)) {
    try {
      return delta(name, out, version, progress);
    } catch (const NotFoundError&) {
      throw;
    } catch (const std::exception& e) {
      fallback = e.what();  // a full download, below
    }
  }
  try {
    DownloadResult r = fetch(name, out, version, progress);
    r.fallback = fallback;
    return r;
  } catch (const CorruptError&) {
    if (!resuming) throw;
    DownloadResult r = fetch(name, out, version, progress);  // the partial file was bad; it is gone now
    r.fallback = fallback;
    return r;
  }
}

}  // namespace btfvq::cli
