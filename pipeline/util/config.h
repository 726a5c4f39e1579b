#pragma once
// A parameter dictionary over JSON, in the manner of pbrt-v4's: every key that is read is marked,
// and `check_unused()` turns every key nobody asked for into a ConfigError, so that a misspelled
// setting is an error instead of a silently ignored default.
#include <nlohmann/json.hpp>

#include <set>
#include <string>

namespace btfvq {

class ParameterDictionary {
 public:
  ParameterDictionary() : root_(nlohmann::json::object()) {}
  // `origin` names the source in error messages (a file path, "request body", ...).
  ParameterDictionary(nlohmann::json root, std::string origin);

  // Parses JSON text; malformed JSON throws ConfigError naming the origin and position.
  static ParameterDictionary parse(const std::string& text, const std::string& origin);
  static ParameterDictionary load_file(const std::string& path);
  // An embedded default config, e.g. "pipeline" -> configs/pipeline.json.
  static ParameterDictionary embedded_default(const std::string& name);

  // Merges `overrides` on top of this dictionary (objects recursively). Keys of `overrides` that
  // do not exist here are kept, so that check_unused() later reports them.
  void merge(const ParameterDictionary& overrides);

  // Typed getters for dotted keys ("phase1.fraction"). A missing key throws ConfigError; a value of
  // the wrong type, NaN or infinite, or outside [lo, hi] throws ConfigError naming key and origin.
  double number(const std::string& key, double lo, double hi) const;
  int integer(const std::string& key, int lo, int hi) const;
  bool boolean(const std::string& key) const;
  std::string string(const std::string& key) const;
  bool has(const std::string& key) const;

  // Throws ConfigError listing every leaf key that no getter read.
  void check_unused() const;

  const nlohmann::json& json() const { return root_; }
  const std::string& origin() const { return origin_; }

 private:
  const nlohmann::json& lookup(const std::string& key) const;

  nlohmann::json root_;
  std::string origin_ = "defaults";
  mutable std::set<std::string> used_;
};

}  // namespace btfvq
