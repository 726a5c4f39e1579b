#pragma once
// Text resources compiled into the library: OpenCL C sources (kernels/*.cl) and default configs
// (configs/*.json), so that an installed binary needs no source tree.
#include <map>
#include <string>

namespace btfvq {

// Keys are "kernels/NAME.cl", "configs/NAME.json" and "viewer/NAME.{html,js,css}" (the browser viewer).
const std::map<std::string, std::string>& embedded_resources();

// The text of one resource; throws NotFoundError naming the key.
const std::string& embedded_resource(const std::string& key);

}  // namespace btfvq
