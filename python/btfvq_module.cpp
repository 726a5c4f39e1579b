// `import btfvq`: the decode API (include/btfvq/renderer_api.h), the sample reader and the compress
// entry point (pipeline/encode/compress.h) over whole NumPy arrays. Every array call checks its
// input with the GIL held, then releases the GIL and runs over every core through the library's one
// parallel-for (pipeline/util/parallel.h); evaluation goes through the batch decoder
// (Decoder::decode: OpenCL when it is in use) exactly as a C++ batch caller would. docs/python.md
// documents the API; python/tests/test_btfvq.py checks it against the C++ API.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include <btfvq/error.h>
#include <btfvq/renderer_api.h>

#include "pipeline/btf.h"
#include "pipeline/codebook.h"
#include "pipeline/decode/decoder.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/encode/compress.h"
#include "pipeline/encode/quality.h"
#include "pipeline/encode/target.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/util/parallel.h"

namespace py = pybind11;
using namespace btfvq;

namespace {

static_assert(sizeof(Rgb) == 3 * sizeof(float), "Rgb is three packed floats (copied to (N, 3) float32 at once)");

// ---------------------------------------------------------------------------------------------------
// Exceptions: btfvq.Error and its subclasses mirror include/btfvq/error.h; InputError is also a
// ValueError and NotFoundError a LookupError, so generic Python handlers catch them too.
struct Exceptions {
  PyObject* error = nullptr;
  PyObject* input = nullptr;
  PyObject* config = nullptr;
  PyObject* corrupt = nullptr;
  PyObject* not_found = nullptr;
  PyObject* device = nullptr;
  PyObject* cancelled = nullptr;
};
Exceptions g_exc;

PyObject* new_exception(py::module_& m, const char* name, const char* doc, PyObject* bases) {
  const std::string qualified = std::string("btfvq.") + name;
  PyObject* cls = PyErr_NewExceptionWithDoc(qualified.c_str(), doc, bases, nullptr);
  if (!cls) throw py::error_already_set();
  m.add_object(name, py::reinterpret_borrow<py::object>(cls));
  return cls;
}

void raise(PyObject* cls, const std::string& code, const char* message) {
  py::object instance = py::reinterpret_borrow<py::object>(cls)(py::str(message));
  instance.attr("code") = code;
  PyErr_SetObject(cls, instance.ptr());
}

void translate_errors(std::exception_ptr p) {
  try {
    if (p) std::rethrow_exception(p);
  } catch (const ConfigError& e) {
    raise(g_exc.config, e.code(), e.what());
  } catch (const InputError& e) {
    raise(g_exc.input, e.code(), e.what());
  } catch (const CorruptError& e) {
    raise(g_exc.corrupt, e.code(), e.what());
  } catch (const NotFoundError& e) {
    raise(g_exc.not_found, e.code(), e.what());
  } catch (const DeviceError& e) {
    raise(g_exc.device, e.code(), e.what());
  } catch (const CancelledError& e) {
    raise(g_exc.cancelled, e.code(), e.what());
  } catch (const Error& e) {
    raise(g_exc.error, e.code(), e.what());
  }
}

[[noreturn]] void bad_input(const std::string& message) { throw InputError(message); }

// ---------------------------------------------------------------------------------------------------
// Array arguments: (N, k) or (k,) (one value for every query), any real dtype (converted to float64).
struct Rows {
  py::array_t<double, py::array::c_style | py::array::forcecast> array;
  const double* data = nullptr;
  size_t n = 1, k = 0;
  bool broadcast = false;
  const double* row(size_t i) const { return data + (broadcast ? 0 : i * k); }
};

Rows rows_of(const py::handle& obj, const char* what, std::initializer_list<size_t> widths) {
  if (obj.is_none()) bad_input(std::string(what) + " is missing");
  py::array raw = py::array::ensure(obj);
  if (!raw) bad_input(std::string(what) + " is not an array");
  const char kind = raw.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u')
    bad_input(std::string(what) + " has dtype " + std::string(py::str(raw.dtype())) + "; a real number type is needed");
  Rows r;
  r.array = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(raw);
  if (!r.array) throw py::error_already_set();
  const auto shape_text = [&] {
    std::string s = "(";
    for (py::ssize_t d = 0; d < r.array.ndim(); ++d) s += (d ? ", " : "") + std::to_string(r.array.shape(d));
    return s + (r.array.ndim() == 1 ? ",)" : ")");
  };
  std::string allowed;
  for (size_t w : widths) allowed += std::string(allowed.empty() ? "" : " or ") + "(N, " + std::to_string(w) + ")";
  if (r.array.ndim() == 1) {
    r.broadcast = true;
    r.k = size_t(r.array.shape(0));
  } else if (r.array.ndim() == 2) {
    r.n = size_t(r.array.shape(0));
    r.k = size_t(r.array.shape(1));
  } else {
    bad_input(std::string(what) + " has shape " + shape_text() + "; expected " + allowed);
  }
  bool ok = false;
  for (size_t w : widths) ok = ok || r.k == w;
  if (!ok) bad_input(std::string(what) + " has shape " + shape_text() + "; expected " + allowed);
  r.data = r.array.data();
  const size_t count = r.broadcast ? r.k : r.n * r.k;
  for (size_t i = 0; i < count; ++i)
    if (!std::isfinite(r.data[i]))
      bad_input(std::string(what) + (r.broadcast ? "" : "[" + std::to_string(i / r.k) + "]") + " is not finite (NaN or inf)");
  if (r.k == 3)
    for (size_t i = 0; i < (r.broadcast ? 1 : r.n); ++i) {
      const double* p = r.row(i);
      if (p[0] == 0 && p[1] == 0 && p[2] == 0)
        bad_input(std::string(what) + (r.broadcast ? "" : "[" + std::to_string(i) + "]") + " is the zero vector");
    }
  return r;
}

// The query count of arguments that are (N, k) or broadcast (k,); every (N, k) must agree.
struct Batch {
  size_t n = 1;
  bool all_broadcast = true;
};
Batch batch_of(std::initializer_list<const Rows*> args) {
  Batch b;
  const Rows* first = nullptr;
  for (const Rows* r : args) {
    if (r->broadcast) continue;
    if (first && r->n != first->n)
      bad_input("arrays of different lengths: " + std::to_string(first->n) + " and " + std::to_string(r->n) + " rows");
    first = r;
    b.n = r->n;
    b.all_broadcast = false;
  }
  return b;
}

Direction direction_of(const Rows& r, size_t i) {
  const double* p = r.row(i);
  return r.k == 3 ? to_direction({p[0], p[1], p[2]}) : Direction{p[0], p[1]};
}
Vec3 vector_of(const Rows& r, size_t i) {
  const double* p = r.row(i);
  return r.k == 3 ? Vec3{p[0], p[1], p[2]} : to_vector(Direction{p[0], p[1]});
}

// A result array of (N, width) (or (width,) when every input was one value), or (N,) for width 0.
template <class T>
py::array_t<T> result(const Batch& b, size_t width) {
  if (width == 0) return b.all_broadcast ? py::array_t<T>(std::vector<py::ssize_t>{}) : py::array_t<T>(py::ssize_t(b.n));
  if (b.all_broadcast) return py::array_t<T>(py::ssize_t(width));
  return py::array_t<T>({py::ssize_t(b.n), py::ssize_t(width)});
}

std::string path_of(const py::handle& obj) {
  py::object fs = py::module_::import("os").attr("fspath")(obj);
  if (!py::isinstance<py::str>(fs)) bad_input("a path must be a str or os.PathLike of str");
  return fs.cast<std::string>();
}

// ---------------------------------------------------------------------------------------------------
// Python callbacks called from library threads: the GIL is taken for the call; a Python exception
// is kept (the first one), the work is cancelled, and the exception is raised again in the caller.
class Callback {
 public:
  explicit Callback(py::object fn) : fn_(std::move(fn)) {}
  bool empty() const { return fn_.is_none(); }
  template <class... A>
  void operator()(A&&... args) {
    if (fn_.is_none() || failed()) return;
    py::gil_scoped_acquire gil;
    try {
      fn_(std::forward<A>(args)...);
    } catch (py::error_already_set&) {
      std::lock_guard<std::mutex> lock(m_);
      if (!error_) error_ = std::current_exception();
    }
    if (failed()) throw CancelledError("cancelled by an exception in the progress callback");
  }
  // KeyboardInterrupt (Ctrl-C) while the call runs: PyErr_CheckSignals acts in the main thread only.
  bool interrupted() {
    if (failed()) return true;
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) {
      std::lock_guard<std::mutex> lock(m_);
      if (!error_) {
        try {
          throw py::error_already_set();
        } catch (py::error_already_set&) {
          error_ = std::current_exception();
        }
      }
    }
    return failed();
  }
  bool failed() {
    std::lock_guard<std::mutex> lock(m_);
    return bool(error_);
  }
  // With the GIL held: raises the kept Python exception, if any.
  void rethrow() {
    std::exception_ptr e;
    {
      std::lock_guard<std::mutex> lock(m_);
      e = error_;
    }
    if (e) std::rethrow_exception(e);
  }
  ~Callback() {
    // error_already_set releases its Python objects with the GIL; our destructor runs with it held.
    std::lock_guard<std::mutex> lock(m_);
    error_ = nullptr;
  }

 private:
  py::object fn_;
  std::mutex m_;
  std::exception_ptr error_;
};

// Runs `work` with the GIL released; a C++ exception comes out with the GIL held again, so a kept
// Python exception (from a callback) wins over the CancelledError that stopped the work.
template <class F>
auto without_gil(Callback* cb, F&& work) {
  try {
    py::gil_scoped_release release;
    return work();
  } catch (...) {
    if (cb) cb->rethrow();
    throw;
  }
}

// ---------------------------------------------------------------------------------------------------
// Samples as arrays: MeasuredSample's texel-major storage is exactly (H, W, views, lights, 3) when
// every view has the same lights (texel = row * W + column, pair = view * lights + light).
template <class T>
py::array owning_array(std::vector<T>&& data, const std::vector<py::ssize_t>& shape) {
  auto* heap = new std::vector<T>(std::move(data));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, heap->data(), owner);
}

py::array sample_array(MeasuredSample&& s) {
  const size_t lights = s.view_count() ? s.lights(0).size() : 0;
  for (size_t v = 0; v < s.view_count(); ++v)
    if (s.lights(v).size() != lights) bad_input("the sample's views do not all have the same lights");
  const std::vector<py::ssize_t> shape{s.height(), s.width(), py::ssize_t(s.view_count()), py::ssize_t(lights), 3};
  if (s.is_hdr()) return owning_array(std::move(s.hdr_data()), shape);
  return owning_array(std::move(s.ldr_data()), shape);
}

py::tuple directions_of(const MeasuredSample& s) {
  const size_t lights = s.view_count() ? s.lights(0).size() : 0;
  py::array_t<double> views({py::ssize_t(s.view_count()), py::ssize_t(2)});
  py::array_t<double> ls({py::ssize_t(s.view_count()), py::ssize_t(lights), py::ssize_t(2)});
  auto vw = views.mutable_unchecked<2>();
  auto lw = ls.mutable_unchecked<3>();
  for (size_t v = 0; v < s.view_count(); ++v) {
    vw(v, 0) = s.views()[v].theta;
    vw(v, 1) = s.views()[v].phi;
    for (size_t l = 0; l < lights; ++l) {
      lw(v, l, 0) = s.lights(v)[l].theta;
      lw(v, l, 1) = s.lights(v)[l].phi;
    }
  }
  return py::make_tuple(views, ls);
}

std::vector<Direction> directions_from(const py::handle& obj, const char* what, size_t count) {
  auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(obj);
  if (!a || a.ndim() != 2 || a.shape(1) != 2 || size_t(a.shape(0)) != count)
    bad_input(std::string(what) + " must be an array of shape (" + std::to_string(count) + ", 2): theta, phi in degrees");
  std::vector<Direction> out(count);
  for (size_t i = 0; i < count; ++i) out[i] = {a.at(i, 0), a.at(i, 1)};
  return out;
}

// An (H, W, views, lights, 3) array as a MeasuredSample: uint8 is LDR (gamma-encoded 0..255),
// float32/float64 is HDR (linear). Directions default to the Bonn 81 x 81 when the shape is
// (H, W, 81, 81, 3); otherwise `views` (V, 2) and `lights` (L, 2) or (V, L, 2) are required.
MeasuredSample sample_from_array(const py::array& raw, const py::object& views_obj, const py::object& lights_obj) {
  if (raw.ndim() != 5 || raw.shape(4) != 3)
    bad_input("a sample array must have shape (H, W, views, lights, 3)");
  const char kind = raw.dtype().kind();
  const bool ldr = kind == 'u' && raw.itemsize() == 1;
  if (!ldr && kind != 'f') bad_input("a sample array must be uint8 (LDR) or float32/float64 (HDR, linear)");
  const int h = int(raw.shape(0)), w = int(raw.shape(1));
  const size_t nv = size_t(raw.shape(2)), nl = size_t(raw.shape(3));
  if (h <= 0 || w <= 0 || nv == 0 || nl == 0) bad_input("a sample array must not be empty");
  std::vector<Direction> views;
  std::vector<std::vector<Direction>> lights;
  if (views_obj.is_none() && lights_obj.is_none()) {
    if (nv != bonn81().size() || nl != bonn81().size())
      bad_input("a sample array that is not (H, W, 81, 81, 3) needs views= (V, 2) and lights= (L, 2) or (V, L, 2)");
    views = bonn81();
    lights.assign(nv, bonn81());
  } else {
    if (views_obj.is_none() || lights_obj.is_none()) bad_input("views= and lights= go together");
    views = directions_from(views_obj, "views", nv);
    auto la = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(lights_obj);
    if (la && la.ndim() == 3) {
      if (size_t(la.shape(0)) != nv || size_t(la.shape(1)) != nl || la.shape(2) != 2)
        bad_input("lights must have shape (L, 2) or (V, L, 2) matching the array");
      for (size_t v = 0; v < nv; ++v) {
        std::vector<Direction> l(nl);
        for (size_t i = 0; i < nl; ++i) l[i] = {la.at(v, i, 0), la.at(v, i, 1)};
        lights.push_back(std::move(l));
      }
    } else {
      lights.assign(nv, directions_from(lights_obj, "lights", nl));
    }
  }
  MeasuredSample s(w, h, views, lights, ldr ? Dynamic::LDR : Dynamic::HDR);
  if (ldr) {
    auto a = py::array_t<uint8_t, py::array::c_style>::ensure(raw);
    std::memcpy(s.ldr_data().data(), a.data(), s.ldr_data().size());
  } else {
    auto a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(raw);
    const float* p = a.data();
    for (size_t i = 0; i < s.hdr_data().size(); ++i)
      if (!std::isfinite(p[i]) || p[i] < 0) bad_input("an HDR sample array holds a negative or non-finite value");
    std::memcpy(s.hdr_data().data(), p, s.hdr_data().size() * sizeof(float));
  }
  return s;
}

py::object json_to_python(const nlohmann::json& j) {
  return py::module_::import("json").attr("loads")(j.dump());
}

// ---------------------------------------------------------------------------------------------------
// The Python objects.
struct PyDatabase {
  BtfDatabase db;
  std::string path;
};

struct PyMaterial {
  BtfDatabase db;  // keeps the state alive (as the material handle does), for the batch layers
  BtfMaterial mat;
};

// Evaluation: the batch decoder on the current compute device (OpenCL when in use; on the C++ path
// Decoder::evaluate per query, what BtfMaterial::evaluate calls, over every core).
py::array_t<float> evaluate(const PyMaterial& m, const py::object& uv_o, const py::object& light_o, const py::object& view_o) {
  const Rows uv = rows_of(uv_o, "uv", {2});
  const Rows light = rows_of(light_o, "light", {3, 2});
  const Rows view = rows_of(view_o, "view", {3, 2});
  const Batch b = batch_of({&uv, &light, &view});
  py::array_t<float> out = result<float>(b, 3);
  float* dst = out.mutable_data();
  without_gil(nullptr, [&] {
    const uint32_t index = uint32_t(m.mat.index());
    // Straight from the arrays into the result: no query vector, no second copy of the values.
    m.db.decoder().decode(b.n, [&](size_t i) {
      const double* t = uv.row(i);
      return DecodeQuery{index, m.mat.texel_x(t[0]), m.mat.texel_y(t[1]), direction_of(light, i), direction_of(view, i)};
    }, reinterpret_cast<Rgb*>(dst));
    return 0;
  });
  return out;
}

py::tuple sample(const PyMaterial& m, const py::object& uv_o, const py::object& view_o, const py::object& xi_o) {
  const Rows uv = rows_of(uv_o, "uv", {2});
  const Rows view = rows_of(view_o, "view", {3, 2});
  const Rows xi = rows_of(xi_o, "xi", {2});
  const Batch b = batch_of({&uv, &view, &xi});
  py::array_t<double> dirs = result<double>(b, 3);
  py::array_t<double> pdf = result<double>(b, 0);
  double* d = dirs.mutable_data();
  double* p = pdf.mutable_data();
  without_gil(nullptr, [&] {
    parallel_for(0, b.n, [&](size_t first, size_t last) {
      for (size_t i = first; i < last; ++i) {
        const double* t = uv.row(i);
        const double* x = xi.row(i);
        const BtfSample s = m.mat.sample(t[0], t[1], vector_of(view, i), x[0], x[1]);
        d[3 * i] = s.direction.x;
        d[3 * i + 1] = s.direction.y;
        d[3 * i + 2] = s.direction.z;
        p[i] = s.pdf;
      }
    });
    return 0;
  });
  return py::make_tuple(dirs, pdf);
}

py::array_t<double> pdf(const PyMaterial& m, const py::object& uv_o, const py::object& light_o, const py::object& view_o) {
  const Rows uv = rows_of(uv_o, "uv", {2});
  const Rows light = rows_of(light_o, "light", {3, 2});
  const Rows view = rows_of(view_o, "view", {3, 2});
  const Batch b = batch_of({&uv, &light, &view});
  py::array_t<double> out = result<double>(b, 0);
  double* p = out.mutable_data();
  without_gil(nullptr, [&] {
    parallel_for(0, b.n, [&](size_t first, size_t last) {
      for (size_t i = first; i < last; ++i) {
        const double* t = uv.row(i);
        p[i] = m.mat.pdf(t[0], t[1], vector_of(light, i), vector_of(view, i));
      }
    });
    return 0;
  });
  return out;
}

py::array_t<float> albedo(const PyMaterial& m, const py::object& uv_o, const py::object& view_o) {
  const Rows uv = rows_of(uv_o, "uv", {2});
  const Rows view = rows_of(view_o, "view", {3, 2});
  const Batch b = batch_of({&uv, &view});
  py::array_t<float> out = result<float>(b, 3);
  float* dst = out.mutable_data();
  without_gil(nullptr, [&] {
    // About 900 evaluations per query: one query per index is a fine grain.
    parallel_for(0, b.n, [&](size_t i) {
      const double* t = uv.row(i);
      const Rgb c = m.mat.albedo(t[0], t[1], vector_of(view, i));
      std::memcpy(dst + 3 * i, &c, sizeof c);
    }, ParallelOptions{.threads = 0, .grain = 1});
    return 0;
  });
  return out;
}

py::object decode_material(const PyMaterial& m, const py::object& views_o, const py::object& lights_o) {
  MeasuredSample geometry;
  if (views_o.is_none() && lights_o.is_none()) {
    geometry = make_bonn_sample(1, 1, m.mat.hdr() ? Dynamic::HDR : Dynamic::LDR);
  } else {
    if (views_o.is_none() || lights_o.is_none()) bad_input("views= and lights= go together");
    auto va = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(views_o);
    auto la = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(lights_o);
    if (!va || va.ndim() != 2 || va.shape(1) != 2 || va.shape(0) == 0) bad_input("views must have shape (V, 2)");
    if (!la || la.ndim() != 2 || la.shape(1) != 2 || la.shape(0) == 0) bad_input("lights must have shape (L, 2)");
    const std::vector<Direction> views = directions_from(va, "views", size_t(va.shape(0)));
    const std::vector<Direction> lights = directions_from(la, "lights", size_t(la.shape(0)));
    for (const auto* set : {&views, &lights})
      for (const Direction& d : *set)
        if (!std::isfinite(d.theta) || !std::isfinite(d.phi)) bad_input("a direction is not finite (NaN or inf)");
    geometry = MeasuredSample(1, 1, views, std::vector<std::vector<Direction>>(views.size(), lights),
                              m.mat.hdr() ? Dynamic::HDR : Dynamic::LDR);
  }
  MeasuredSample s = without_gil(nullptr, [&] {
    return reconstruct_sample(m.db.database(), m.mat.name(), geometry, int(parallel_threads()));
  });
  return sample_array(std::move(s));
}

py::object read_sample(const py::object& path_o, const py::object& progress, bool directions) {
  const std::string path = path_of(path_o);
  Callback cb(progress);
  ProgressFn fn;
  if (!cb.empty()) fn = [&cb](size_t done, size_t total) { cb(done, total); };
  MeasuredSample s = without_gil(&cb, [&] { return load_sample(path, fn); });
  if (!directions) return sample_array(std::move(s));
  py::tuple dirs = directions_of(s);
  return py::make_tuple(sample_array(std::move(s)), dirs[0], dirs[1]);
}

py::dict progress_dict(const CompressProgress& p) {
  py::dict d;
  d["stage"] = p.stage;
  d["phase"] = p.phase;
  d["done"] = p.texels_done;
  d["total"] = p.texels_total;
  d["fraction"] = p.fraction;
  d["material"] = p.material;
  d["material_index"] = p.material_index;
  d["materials"] = p.materials;
  return d;
}

py::dict compress(const py::object& sample_o, const py::object& db_o, const py::object& name_o,
                  const py::object& quality, const py::object& target_mssim, const py::object& config,
                  const py::object& progress, const py::object& views, const py::object& lights) {
  const std::string out = path_of(db_o);
  if (!quality.is_none() && !target_mssim.is_none()) bad_input("quality and target_mssim exclude each other");
  // The same settings rule as `btfvq compress` (client/cmd_compress.cpp): quality sets every
  // threshold, `config` (a configs/pipeline.json fragment) wins over it key by key.
  const nlohmann::json overrides =
      config.is_none() ? nlohmann::json() : nlohmann::json::parse(py::module_::import("json").attr("dumps")(config).cast<std::string>());
  CompressOptions options;
  if (!quality.is_none()) {
    const double q = quality.cast<double>();
    if (!std::isfinite(q) || q < 0 || q > 100) bad_input("quality must be in 0..100");
    options.config = pipeline_config(with_quality(q, overrides), "quality");
  } else {
    options.config = pipeline_config(overrides, "config");
  }
  if (!target_mssim.is_none()) {
    QualityTarget t;
    t.value = target_mssim.cast<double>();
    if (!(t.value >= 0.01 && t.value <= 0.999)) bad_input("target_mssim must be in 0.01..0.999");
    t.overrides = overrides;
    options.target = t;
  }
  MaterialInput input;
  if (py::isinstance<py::array>(sample_o)) {
    if (name_o.is_none()) bad_input("name= is needed to compress an array");
    input.name = name_o.cast<std::string>();
    auto s = std::make_shared<MeasuredSample>(sample_from_array(py::reinterpret_borrow<py::array>(sample_o), views, lights));
    input.load_stage = "array";
    input.load = [s](const std::function<void(size_t, size_t)>&) { return std::move(*s); };
  } else {
    const std::string path = path_of(sample_o);
    if (name_o.is_none()) {
      // As `btfvq compress` names it (client/cli.cpp material_name_of): the last path part, less ".zip".
      std::filesystem::path p(path);
      while (!p.empty() && p.filename().empty()) p = p.parent_path();
      input.name = p.filename().string();
      if (input.name.size() > 4 && input.name.substr(input.name.size() - 4) == ".zip") input.name.resize(input.name.size() - 4);
    } else {
      input.name = name_o.cast<std::string>();
    }
    input.load = [path](const std::function<void(size_t, size_t)>& p) { return load_sample(path, p); };
  }
  Callback cb(progress);
  if (!cb.empty()) options.progress = [&cb](const CompressProgress& p) {
    if (cb.failed()) return;
    py::gil_scoped_acquire gil;
    py::dict d = progress_dict(p);
    cb(d);
  };
  options.cancelled = [&cb] { return cb.interrupted(); };
  const DatabaseSummary summary = without_gil(&cb, [&] { return compress_database(out, {input}, out, options); });
  py::dict r;
  r["path"] = out;
  r["bytes"] = summary.bytes;
  r["raw_bytes"] = summary.raw_bytes;
  r["ratio"] = summary.ratio;
  r["materials"] = summary.materials;
  py::list added;
  for (const auto& a : summary.added) {
    py::dict m;
    m["name"] = a.material;
    m["width"] = a.width;
    m["height"] = a.height;
    m["raw_bytes"] = a.raw_bytes;
    m["report"] = json_to_python(a.json);
    added.append(m);
  }
  r["added"] = added;
  return r;
}

PyMaterial material_of(const PyDatabase& d, const py::object& key) {
  if (py::isinstance<py::int_>(key)) {
    const long long i = key.cast<long long>();
    const long long n = (long long)d.db.database().materials.size();
    if (i < -n || i >= n) throw NotFoundError("material index " + std::to_string(i) + " is out of range (" + std::to_string(n) + " materials)");
    return {d.db, d.db.material(size_t(i < 0 ? i + n : i))};
  }
  if (!py::isinstance<py::str>(key)) bad_input("a material is named by a str or an int index");
  return {d.db, d.db.material(key.cast<std::string>())};
}

}  // namespace

PYBIND11_MODULE(btfvq, m) {
  m.doc() =
      "btfvq: measured BTF databases (.btfdb, or a BTFBASE directory of the original compressor) over NumPy "
      "arrays. See docs/python.md.\n\n"
      "Directions are tangent-frame vectors (z the normal, x the tangent at azimuth 0) of shape (N, 3), or "
      "(N, 2) arrays of (theta, phi) in degrees; uv is (N, 2). A (k,) array stands for the same value in "
      "every query. Results are (N, 3) float32 RGB (gamma-encoded 0..255 for LDR, linear for HDR), pdfs "
      "(N,) float64 in 1/sr. Every call releases the GIL and uses every core.";
  m.attr("__version__") = "0.1.0";

  g_exc.error = new_exception(m, "Error",
                              "Base of every error btfvq raises on purpose; `code` is a stable tag (e.g. 'corrupt').",
                              PyExc_Exception);
  {
    py::tuple bases = py::make_tuple(py::handle(g_exc.error), py::handle(PyExc_ValueError));
    g_exc.input = new_exception(m, "InputError", "The caller's input is wrong: a bad array shape, NaN, a bad file or value.",
                                bases.ptr());
  }
  g_exc.config = new_exception(m, "ConfigError", "A compress setting is unknown, has the wrong type or is out of range.",
                               g_exc.input);
  g_exc.corrupt = new_exception(m, "CorruptError", "A stored file (database, archive) is truncated or damaged.", g_exc.error);
  {
    py::tuple bases = py::make_tuple(py::handle(g_exc.error), py::handle(PyExc_LookupError));
    g_exc.not_found = new_exception(m, "NotFoundError", "Something looked up by name is not there (a material).", bases.ptr());
  }
  g_exc.device = new_exception(m, "DeviceError", "The compute device (OpenCL) failed.", g_exc.error);
  g_exc.cancelled = new_exception(m, "CancelledError", "The operation was cancelled.", g_exc.error);
  py::register_exception_translator(translate_errors);

  py::class_<PyMaterial>(m, "Material", "One material of a database (immutable; safe from any thread).")
      .def_property_readonly("name", [](const PyMaterial& x) { return x.mat.name(); })
      .def_property_readonly("width", [](const PyMaterial& x) { return x.mat.width(); })
      .def_property_readonly("height", [](const PyMaterial& x) { return x.mat.height(); })
      .def_property_readonly("hdr", [](const PyMaterial& x) { return x.mat.hdr(); })
      .def_property_readonly("index", [](const PyMaterial& x) { return x.mat.index(); })
      .def("__repr__", [](const PyMaterial& x) {
        return "<btfvq.Material '" + x.mat.name() + "' " + std::to_string(x.mat.width()) + "x" +
               std::to_string(x.mat.height()) + (x.mat.hdr() ? " HDR" : " LDR") + ">";
      })
      .def("evaluate", &evaluate, py::arg("uv"), py::arg("light"), py::arg("view"),
           "BTF values (N, 3) float32 for uv (N, 2), light and view (N, 3) vectors or (N, 2) theta/phi degrees. "
           "Zero below the horizon. Runs on the batch decoder (OpenCL when in use).")
      .def("sample", &sample, py::arg("uv"), py::arg("view"), py::arg("xi"),
           "Importance-samples light directions for view from xi (N, 2) uniform in [0, 1]: returns "
           "(directions (N, 3) float64 unit vectors, pdf (N,) float64 in 1/sr).")
      .def("pdf", &pdf, py::arg("uv"), py::arg("light"), py::arg("view"),
           "The density (N,) float64 (1/sr) that sample() draws light with, for view.")
      .def("albedo", &albedo, py::arg("uv"), py::arg("view"),
           "Integral over the hemisphere of evaluate() x cos(theta_i) (N, 3) float32 (about 900 evaluations each).")
      .def("decode", &decode_material, py::arg("views") = py::none(), py::arg("lights") = py::none(),
           "The whole material decoded at the measured directions: (H, W, views, lights, 3), uint8 for LDR "
           "(rounded, clamped), float32 for HDR. Default: the Bonn 81 x 81 directions (btfvq.bonn81()); "
           "views (V, 2) and lights (L, 2) in degrees otherwise.");

  py::class_<PyDatabase>(m, "Database", "An opened database (immutable; safe from any thread).")
      .def_property_readonly("path", [](const PyDatabase& d) { return d.path; })
      .def_property_readonly("names", [](const PyDatabase& d) { return d.db.material_names(); })
      .def_property_readonly("materials", [](const PyDatabase& d) {
        std::vector<PyMaterial> out;
        for (size_t i = 0; i < d.db.database().materials.size(); ++i) out.push_back({d.db, d.db.material(i)});
        return out;
      })
      .def("material", &material_of, py::arg("key"), "The material of that name or index; NotFoundError if absent.")
      .def("__getitem__", &material_of)
      .def("__len__", [](const PyDatabase& d) { return d.db.database().materials.size(); })
      .def("__contains__", [](const PyDatabase& d, const std::string& name) { return d.db.database().find(name) != nullptr; })
      .def("__repr__", [](const PyDatabase& d) {
        return "<btfvq.Database '" + d.path + "' " + std::to_string(d.db.database().materials.size()) + " material(s)>";
      });

  m.def("open", [](const py::object& path_o) {
    const std::string path = path_of(path_o);
    BtfDatabase db = without_gil(nullptr, [&] { return BtfDatabase::open(path); });
    return PyDatabase{std::move(db), path};
  }, py::arg("path"), "Opens a .btfdb file or a BTFBASE directory. InputError (missing), CorruptError (damaged).");

  m.def("read_sample", &read_sample, py::arg("path"), py::arg("progress") = py::none(), py::arg("directions") = false,
        "Reads a UBO2003 zip or folder into (H, W, views, lights, 3): uint8 for LDR JPEG/PNG, float32 for "
        "HDR EXR. progress(done, total) is called per image. directions=True returns (array, views (V, 2), "
        "lights (V, L, 2)) in degrees.");

  m.def("compress", &compress, py::arg("sample"), py::kw_only(), py::arg("db"), py::arg("name") = py::none(),
        py::arg("quality") = py::none(), py::arg("target_mssim") = py::none(), py::arg("config") = py::none(),
        py::arg("progress") = py::none(), py::arg("views") = py::none(), py::arg("lights") = py::none(),
        "Compresses a sample (a zip/folder path, or an (H, W, views, lights, 3) array: uint8 LDR or float "
        "HDR) as material `name` into the database `db` (created, or gaining the material), through the "
        "same compress_database() call as `btfvq compress`. quality 0..100 or target_mssim, config a "
        "configs/pipeline.json fragment (a dict). progress(dict) gets stage, phase, done, total, fraction; "
        "an exception it raises cancels the compression and is raised again. Returns a summary dict.");

  m.def("bonn81", [] {
    py::array_t<double> out({py::ssize_t(81), py::ssize_t(2)});
    auto w = out.mutable_unchecked<2>();
    for (size_t i = 0; i < 81; ++i) {
      w(i, 0) = bonn81()[i].theta;
      w(i, 1) = bonn81()[i].phi;
    }
    return out;
  }, "The 81 Bonn directions (theta, phi) in degrees: the view and light order of read_sample/decode arrays.");

  m.def("device", [] { return ComputeDevice::get().description(); },
        "What evaluates batches: the OpenCL platform and device, or why the C++ path is used.");
  m.def("set_device", [](const std::string& preference) { ComputeDevice::configure(preference); }, py::arg("preference"),
        "'auto', 'opencl' or 'cpu-reference' (call before other work; the BTFVQ_DEVICE environment variable wins).");
  m.def("threads", [] { return parallel_threads(); }, "Threads a batch call uses (every core).");
}
