// The C++ API's answers and batch throughput on given queries, for the Python module's tests and
// bench (python/tests/test_btfvq.py, bench/bench_python.py), computed here without the module.
//
//   btfvq_reference values DB MATERIAL QUERIES OUT [ALBEDO_COUNT]
//   btfvq_reference bench  DB MATERIAL QUERIES REPEATS
//
// QUERIES: little-endian uint64 n, then n rows of 14 float64:
//   u v | light x y z | view x y z | light theta phi | view theta phi | xi1 xi2      (degrees)
// OUT (values), one block after the other:
//   float32 n x 3  BtfMaterial::evaluate(u, v, light vector, view vector)
//   float32 n x 3  BtfMaterial::evaluate(u, v, light angles, view angles)
//   float32 n x 3  Decoder::decode (the batch path on the current device) of the vector queries
//   float32 n x 3  Decoder::decode of the angle queries
//   float64 n x 3  BtfMaterial::sample(u, v, view vector, xi1, xi2).direction
//   float64 n      its pdf
//   float64 n      BtfMaterial::pdf(u, v, light vector, view vector)
//   float64 n      BtfMaterial::pdf(u, v, to_vector(light angles), to_vector(view angles))
//   float32 a x 3  BtfMaterial::albedo(u, v, view vector) of the first a = ALBEDO_COUNT queries
// bench prints one JSON line: the best of REPEATS timed Decoder::decode calls on the prebuilt angle
// queries (queries per wall second and per CPU second of the process), and the same with the
// queries built from the vectors first.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <ctime>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include <btfvq/error.h>
#include <btfvq/renderer_api.h>

#include "pipeline/decode/decoder.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/util/parallel.h"

using namespace btfvq;

namespace {

constexpr size_t kCols = 14;

std::vector<double> read_queries(const std::string& path, size_t& n) {
  std::ifstream f(path, std::ios::binary);
  uint64_t count = 0;
  f.read(reinterpret_cast<char*>(&count), sizeof count);
  std::vector<double> q(count * kCols);
  f.read(reinterpret_cast<char*>(q.data()), std::streamsize(q.size() * sizeof(double)));
  if (!f) throw InputError("cannot read the queries in " + path);
  n = count;
  return q;
}

template <class T>
void write(std::ofstream& f, const std::vector<T>& v) {
  f.write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * sizeof(T)));
}

Vec3 vec(const double* p) { return {p[0], p[1], p[2]}; }
Direction dir(const double* p) { return {p[0], p[1]}; }

std::vector<DecodeQuery> angle_queries(const BtfMaterial& m, const std::vector<double>& q, size_t n) {
  std::vector<DecodeQuery> out(n);
  for (size_t i = 0; i < n; ++i) {
    const double* r = &q[i * kCols];
    out[i] = {uint32_t(m.index()), m.texel_x(r[0]), m.texel_y(r[1]), dir(r + 8), dir(r + 10)};
  }
  return out;
}

// Built over every core, as a batch caller holding vectors would.
std::vector<DecodeQuery> vector_queries(const BtfMaterial& m, const std::vector<double>& q, size_t n) {
  std::vector<DecodeQuery> out(n);
  parallel_for(0, n, [&](size_t first, size_t last) {
    for (size_t i = first; i < last; ++i) {
      const double* r = &q[i * kCols];
      out[i] = {uint32_t(m.index()), m.texel_x(r[0]), m.texel_y(r[1]), to_direction(vec(r + 2)), to_direction(vec(r + 5))};
    }
  });
  return out;
}

std::vector<float> flat(const std::vector<Rgb>& c) {
  std::vector<float> out;
  for (const Rgb& x : c) out.insert(out.end(), {x.r, x.g, x.b});
  return out;
}

int values(const BtfDatabase& db, const BtfMaterial& m, const std::vector<double>& q, size_t n, const std::string& out,
           size_t albedo_count) {
  std::vector<float> ev, ea, al;
  std::vector<double> sd, sp, pv, pa;
  for (size_t i = 0; i < n; ++i) {
    const double* r = &q[i * kCols];
    const Rgb a = m.evaluate(r[0], r[1], vec(r + 2), vec(r + 5));
    const Rgb b = m.evaluate(r[0], r[1], dir(r + 8), dir(r + 10));
    ev.insert(ev.end(), {a.r, a.g, a.b});
    ea.insert(ea.end(), {b.r, b.g, b.b});
    const BtfSample s = m.sample(r[0], r[1], vec(r + 5), r[12], r[13]);
    sd.insert(sd.end(), {s.direction.x, s.direction.y, s.direction.z});
    sp.push_back(s.pdf);
    pv.push_back(m.pdf(r[0], r[1], vec(r + 2), vec(r + 5)));
    pa.push_back(m.pdf(r[0], r[1], to_vector(dir(r + 8)), to_vector(dir(r + 10))));
  }
  for (size_t i = 0; i < std::min(n, albedo_count); ++i) {
    const double* r = &q[i * kCols];
    const Rgb c = m.albedo(r[0], r[1], vec(r + 5));
    al.insert(al.end(), {c.r, c.g, c.b});
  }
  const std::vector<float> bv = flat(db.decoder().decode(vector_queries(m, q, n)));
  const std::vector<float> ba = flat(db.decoder().decode(angle_queries(m, q, n)));
  std::ofstream f(out, std::ios::binary);
  write(f, ev);
  write(f, ea);
  write(f, bv);
  write(f, ba);
  write(f, sd);
  write(f, sp);
  write(f, pv);
  write(f, pa);
  write(f, al);
  if (!f) throw InputError("cannot write " + out);
  std::cerr << "device: " << ComputeDevice::get().description() << "\n";
  return 0;
}

int bench(const BtfDatabase& db, const BtfMaterial& m, const std::vector<double>& q, size_t n, int repeats) {
  using clock = std::chrono::steady_clock;
  const std::vector<DecodeQuery> prebuilt = angle_queries(m, q, n);
  (void)db.decoder().decode(prebuilt);  // warm-up: kernel build, code-book upload, query buffers
  double wall[2] = {1e30, 1e30}, cpu[2] = {1e30, 1e30};
  for (int k = 0; k < repeats; ++k) {
    for (int form = 0; form < 2; ++form) {
      const auto t0 = clock::now();
      const std::clock_t c0 = std::clock();  // CPU time of the whole process (every thread)
      const std::vector<Rgb> a = db.decoder().decode(form == 0 ? prebuilt : vector_queries(m, q, n));
      const double c = double(std::clock() - c0) / CLOCKS_PER_SEC;
      wall[form] = std::min(wall[form], std::chrono::duration<double>(clock::now() - t0).count());
      cpu[form] = std::min(cpu[form], c);
      if (a.size() != n) return 1;
    }
  }
  std::printf("{\"queries\": %zu, \"repeats\": %d, \"angles_per_s\": %.6g, \"vectors_per_s\": %.6g, "
              "\"angles_per_cpu_s\": %.6g, \"vectors_per_cpu_s\": %.6g, \"device\": \"%s\"}\n",
              n, repeats, double(n) / wall[0], double(n) / wall[1], double(n) / cpu[0], double(n) / cpu[1],
              ComputeDevice::get().description().c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::string usage =
        "usage: btfvq_reference values DB MATERIAL QUERIES OUT [ALBEDO_COUNT] | bench DB MATERIAL QUERIES REPEATS";
    if (argc < 5) throw InputError(usage);
    const std::string mode = argv[1];
    const BtfDatabase db = BtfDatabase::open(argv[2]);
    const BtfMaterial m = db.material(std::string(argv[3]));
    size_t n = 0;
    const std::vector<double> q = read_queries(argv[4], n);
    if (mode == "values" && argc >= 6) return values(db, m, q, n, argv[5], argc >= 7 ? std::stoul(argv[6]) : 0);
    if (mode == "bench" && argc >= 6) return bench(db, m, q, n, std::max(1, std::stoi(argv[5])));
    throw InputError(usage);
  } catch (const std::exception& e) {
    std::cerr << "btfvq_reference: " << e.what() << "\n";
    return 2;
  }
}
