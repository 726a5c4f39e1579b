// The C binding of the renderer API: every entry point catches everything, so no exception crosses
// into C; the error text is kept per thread.
#include <exception>
#include <new>
#include <string>

#include <btfvq/btfvq_c.h>
#include <btfvq/error.h>
#include <btfvq/renderer_api.h>

struct btfvq_database {
  btfvq::BtfDatabase db;
  std::vector<std::string> names;
};

struct btfvq_material {
  btfvq::BtfMaterial mat;
};

namespace {

std::string& last_error() {
  thread_local std::string message;
  return message;
}

btfvq_status fail(btfvq_status status, const std::string& message) {
  last_error() = message;
  return status;
}

// Runs `body`, mapping the library's typed errors to status codes.
template <class F>
btfvq_status guarded(F&& body) {
  try {
    last_error().clear();
    body();
    return BTFVQ_OK;
  } catch (const btfvq::NotFoundError& e) {
    return fail(BTFVQ_NOT_FOUND, e.what());
  } catch (const btfvq::InputError& e) {
    return fail(BTFVQ_INVALID_ARGUMENT, e.what());
  } catch (const btfvq::CorruptError& e) {
    return fail(BTFVQ_CORRUPT, e.what());
  } catch (const btfvq::DeviceError& e) {
    return fail(BTFVQ_DEVICE, e.what());
  } catch (const std::exception& e) {
    return fail(BTFVQ_INTERNAL, e.what());
  } catch (...) {
    return fail(BTFVQ_INTERNAL, "unknown error");
  }
}

btfvq_status null_argument(const char* function, const char* argument) {
  return fail(BTFVQ_INVALID_ARGUMENT, std::string(function) + ": " + argument + " is null");
}

btfvq::Vec3 vec(btfvq_vec3 v) { return {v.x, v.y, v.z}; }

void store(const btfvq::Rgb& c, float rgb[3]) {
  rgb[0] = c.r;
  rgb[1] = c.g;
  rgb[2] = c.b;
}

}  // namespace

extern "C" {

const char* btfvq_last_error(void) { return last_error().c_str(); }

const char* btfvq_status_name(btfvq_status status) {
  switch (status) {
    case BTFVQ_OK: return "ok";
    case BTFVQ_INVALID_ARGUMENT: return "invalid_argument";
    case BTFVQ_NOT_FOUND: return "not_found";
    case BTFVQ_CORRUPT: return "corrupt";
    case BTFVQ_DEVICE: return "device";
    case BTFVQ_INTERNAL: return "internal";
  }
  return "unknown";
}

btfvq_status btfvq_open(const char* path, btfvq_database** out) {
  if (!out) return null_argument("btfvq_open", "out");
  *out = nullptr;
  if (!path) return null_argument("btfvq_open", "path");
  return guarded([&] {
    btfvq::BtfDatabase db = btfvq::BtfDatabase::open(path);
    std::vector<std::string> names = db.material_names();
    *out = new btfvq_database{std::move(db), std::move(names)};
  });
}

void btfvq_close(btfvq_database* db) { delete db; }

btfvq_status btfvq_material_count(const btfvq_database* db, size_t* count) {
  if (!db) return null_argument("btfvq_material_count", "db");
  if (!count) return null_argument("btfvq_material_count", "count");
  *count = db->names.size();
  return BTFVQ_OK;
}

btfvq_status btfvq_material_name(const btfvq_database* db, size_t index, const char** name) {
  if (!db) return null_argument("btfvq_material_name", "db");
  if (!name) return null_argument("btfvq_material_name", "name");
  if (index >= db->names.size())
    return fail(BTFVQ_NOT_FOUND, "material index " + std::to_string(index) + " is past the end (" +
                                     std::to_string(db->names.size()) + " materials)");
  *name = db->names[index].c_str();
  return BTFVQ_OK;
}

btfvq_status btfvq_find_material(const btfvq_database* db, const char* name, btfvq_material** out) {
  if (!out) return null_argument("btfvq_find_material", "out");
  *out = nullptr;
  if (!db) return null_argument("btfvq_find_material", "db");
  if (!name) return null_argument("btfvq_find_material", "name");
  return guarded([&] { *out = new btfvq_material{db->db.material(std::string(name))}; });
}

void btfvq_release_material(btfvq_material* material) { delete material; }

btfvq_status btfvq_material_size(const btfvq_material* m, int* width, int* height, int* hdr) {
  if (!m) return null_argument("btfvq_material_size", "material");
  if (width) *width = m->mat.width();
  if (height) *height = m->mat.height();
  if (hdr) *hdr = m->mat.hdr() ? 1 : 0;
  return BTFVQ_OK;
}

btfvq_status btfvq_evaluate(const btfvq_material* m, double u, double v, btfvq_vec3 light, btfvq_vec3 view, float rgb[3]) {
  if (!m) return null_argument("btfvq_evaluate", "material");
  if (!rgb) return null_argument("btfvq_evaluate", "rgb");
  return guarded([&] { store(m->mat.evaluate(u, v, vec(light), vec(view)), rgb); });
}

btfvq_status btfvq_evaluate_angles(const btfvq_material* m, double u, double v, double theta_i, double phi_i,
                                   double theta_v, double phi_v, float rgb[3]) {
  if (!m) return null_argument("btfvq_evaluate_angles", "material");
  if (!rgb) return null_argument("btfvq_evaluate_angles", "rgb");
  return guarded([&] {
    store(m->mat.evaluate(u, v, btfvq::Direction{theta_i, phi_i}, btfvq::Direction{theta_v, phi_v}), rgb);
  });
}

btfvq_status btfvq_sample(const btfvq_material* m, double u, double v, btfvq_vec3 view, double xi1, double xi2,
                          btfvq_vec3* light, double* pdf) {
  if (!m) return null_argument("btfvq_sample", "material");
  if (!light) return null_argument("btfvq_sample", "light");
  return guarded([&] {
    const btfvq::BtfSample s = m->mat.sample(u, v, vec(view), xi1, xi2);
    *light = {s.direction.x, s.direction.y, s.direction.z};
    if (pdf) *pdf = s.pdf;
  });
}

btfvq_status btfvq_pdf(const btfvq_material* m, double u, double v, btfvq_vec3 light, btfvq_vec3 view, double* pdf) {
  if (!m) return null_argument("btfvq_pdf", "material");
  if (!pdf) return null_argument("btfvq_pdf", "pdf");
  return guarded([&] { *pdf = m->mat.pdf(u, v, vec(light), vec(view)); });
}

btfvq_status btfvq_albedo(const btfvq_material* m, double u, double v, btfvq_vec3 view, float rgb[3]) {
  if (!m) return null_argument("btfvq_albedo", "material");
  if (!rgb) return null_argument("btfvq_albedo", "rgb");
  return guarded([&] { store(m->mat.albedo(u, v, vec(view)), rgb); });
}

}  // extern "C"
