#include "pipeline/runtime/resources.h"

#include <btfvq/error.h>

namespace btfvq {

const std::string& embedded_resource(const std::string& key) {
  const auto& all = embedded_resources();
  auto it = all.find(key);
  if (it == all.end()) throw NotFoundError("no embedded resource '" + key + "'");
  return it->second;
}

}  // namespace btfvq
