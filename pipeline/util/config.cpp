#include "pipeline/util/config.h"

#include <cmath>
#include <fstream>
#include <sstream>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/runtime/resources.h"

namespace btfvq {

namespace {

std::vector<std::string> split_key(const std::string& key) {
  std::vector<std::string> parts;
  std::stringstream ss(key);
  for (std::string p; std::getline(ss, p, '.');) parts.push_back(p);
  return parts;
}

void collect_leaves(const nlohmann::json& j, const std::string& prefix, std::vector<std::string>& out) {
  if (j.is_object() && !j.empty()) {
    for (auto it = j.begin(); it != j.end(); ++it)
      collect_leaves(it.value(), prefix.empty() ? it.key() : prefix + "." + it.key(), out);
  } else {
    out.push_back(prefix);
  }
}

void merge_into(nlohmann::json& base, const nlohmann::json& over) {
  for (auto it = over.begin(); it != over.end(); ++it) {
    if (it.value().is_object() && base.contains(it.key()) && base[it.key()].is_object())
      merge_into(base[it.key()], it.value());
    else
      base[it.key()] = it.value();
  }
}

}  // namespace

ParameterDictionary::ParameterDictionary(nlohmann::json root, std::string origin)
    : root_(std::move(root)), origin_(std::move(origin)) {
  if (!root_.is_object()) throw ConfigError(origin_ + ": the top level must be a JSON object");
}

ParameterDictionary ParameterDictionary::parse(const std::string& text, const std::string& origin) {
  try {
    return ParameterDictionary(nlohmann::json::parse(text), origin);
  } catch (const nlohmann::json::exception& e) {
    throw ConfigError(origin + ": malformed JSON: " + e.what());
  }
}

ParameterDictionary ParameterDictionary::load_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ConfigError("cannot read config file '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse(ss.str(), path);
}

ParameterDictionary ParameterDictionary::embedded_default(const std::string& name) {
  return parse(embedded_resource("configs/" + name + ".json"), "built-in configs/" + name + ".json");
}

void ParameterDictionary::merge(const ParameterDictionary& overrides) {
  merge_into(root_, overrides.root_);
  origin_ = origin_ + " + " + overrides.origin_;
}

const nlohmann::json& ParameterDictionary::lookup(const std::string& key) const {
  const nlohmann::json* j = &root_;
  for (const auto& part : split_key(key)) {
    if (!j->is_object() || !j->contains(part)) throw ConfigError(origin_ + ": missing setting '" + key + "'");
    j = &(*j)[part];
  }
  used_.insert(key);
  return *j;
}

bool ParameterDictionary::has(const std::string& key) const {
  const nlohmann::json* j = &root_;
  for (const auto& part : split_key(key)) {
    if (!j->is_object() || !j->contains(part)) return false;
    j = &(*j)[part];
  }
  return true;
}

double ParameterDictionary::number(const std::string& key, double lo, double hi) const {
  const auto& j = lookup(key);
  if (!j.is_number()) throw ConfigError(origin_ + ": '" + key + "' must be a number");
  const double v = j.get<double>();
  if (!std::isfinite(v) || v < lo || v > hi) {
    std::ostringstream ss;
    ss << origin_ << ": '" << key << "' = " << v << " is outside [" << lo << ", " << hi << "]";
    throw ConfigError(ss.str());
  }
  return v;
}

int ParameterDictionary::integer(const std::string& key, int lo, int hi) const {
  const auto& j = lookup(key);
  if (!j.is_number_integer()) throw ConfigError(origin_ + ": '" + key + "' must be an integer");
  const auto v = j.get<long long>();
  if (v < lo || v > hi)
    throw ConfigError(origin_ + ": '" + key + "' = " + std::to_string(v) + " is outside [" + std::to_string(lo) +
                      ", " + std::to_string(hi) + "]");
  return int(v);
}

bool ParameterDictionary::boolean(const std::string& key) const {
  const auto& j = lookup(key);
  if (!j.is_boolean()) throw ConfigError(origin_ + ": '" + key + "' must be true or false");
  return j.get<bool>();
}

std::string ParameterDictionary::string(const std::string& key) const {
  const auto& j = lookup(key);
  if (!j.is_string()) throw ConfigError(origin_ + ": '" + key + "' must be a string");
  return j.get<std::string>();
}

void ParameterDictionary::check_unused() const {
  std::vector<std::string> leaves;
  collect_leaves(root_, "", leaves);
  std::string unused;
  for (const auto& leaf : leaves) {
    // A leaf counts as used when it, or an object above it, was read.
    bool used = false;
    for (std::string k = leaf;; k = k.substr(0, k.rfind('.'))) {
      if (used_.count(k)) {
        used = true;
        break;
      }
      if (k.find('.') == std::string::npos) break;
    }
    if (!used && !leaf.empty()) unused += (unused.empty() ? "" : ", ") + leaf;
  }
  if (!unused.empty()) throw ConfigError(origin_ + ": unknown setting(s): " + unused);
}

}  // namespace btfvq
