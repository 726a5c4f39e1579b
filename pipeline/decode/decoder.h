#pragma once
// The decoder F(x, y, omega_i, omega_v) of paper Sec. 4.6 / eq. 4, exactly as
// docs/btfbase-format.md "Decoding one value" defines it:
//   P6 -> P4 (linear over phi_v, wrapping) -> P3 (linear over theta_v) -> M -> per M entry:
//   Y = linear in alpha of P2 scale x P1 (cubic Hermite along beta, with the original's tangents),
//   (Cb, Cr) = linear in beta over C(I1), then linear in alpha over I2, then coding space -> RGB
//   (BT.601 studio-swing inverse for LDR, LogLuv for HDR), blended with the P3, P4 and P6 scales.
// Single queries run on the CPU (a renderer's inner loop: no allocation per call); batches run on
// the compute device (kernels/decode.cl) with the code-books uploaded once per Decoder.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <vector>

#include "pipeline/codebook.h"
#include <btfvq/colour.h>
#include <btfvq/directions.h>

namespace btfvq {

// One value to decode: material index into Database::materials, texel (x = column, y = row; wrapped
// modulo the material size), light and view directions in degrees.
struct DecodeQuery {
  uint32_t material = 0;
  int32_t x = 0, y = 0;
  Direction light, view;
};

class Decoder {
 public:
  // Keeps a reference to `db`: the database must outlive the decoder and must not change while it
  // lives (the device copy of the code-books is made once). Throws CorruptError if db does not validate.
  explicit Decoder(const Database& db);
  ~Decoder();
  Decoder(const Decoder&) = delete;
  Decoder& operator=(const Decoder&) = delete;

  const Database& database() const { return db_; }

  // Gamma-encoded RGB (0..255 for LDR, not clamped above; linear radiance for HDR). Zero when either
  // theta exceeds 90 degrees or the texel is not compressed (P6 index -1). Throws NotFoundError for a
  // material index past the end.
  Rgb evaluate(size_t material, int x, int y, const Direction& light, const Direction& view) const;

  // Decodes every query on the current compute device (ComputeDevice::get().backend()).
  // One P4 entry without the P6 scale: every texel that shares the entry is this value times its
  // own P6 scale, which is what makes whole images (reconstruction, previews) cheap.
  Rgb evaluate_p4(uint32_t p4_row, bool hdr, const Direction& light, const Direction& view) const;

  std::vector<Rgb> decode(const std::vector<DecodeQuery>& queries) const;
  // The same batch without a query vector: query(i) gives query i (called from several threads at
  // once, each i once) and its value goes to out[i], out holding n values. On the C++ reference path
  // this is evaluate() per query over every core (pipeline/util/parallel.h). For callers whose
  // queries are in arrays of their own (python/: NumPy arrays), so that nothing is copied twice.
  using QuerySource = std::function<DecodeQuery(size_t)>;
  void decode(size_t n, const QuerySource& query, Rgb* out) const;
  // The plain C++ reference of the batch kernel (evaluate() per query).
  std::vector<Rgb> decode_reference(const std::vector<DecodeQuery>& queries) const;
  // The OpenCL kernel kernels/decode.cl; throws DeviceError when OpenCL is not in use. The angles
  // travel as 32-bit floats and the kernel computes in float (relative difference to
  // decode_reference below 1e-3: tests/test_decoder.cpp).
  std::vector<Rgb> decode_opencl(const std::vector<DecodeQuery>& queries) const;

 private:
  struct DeviceBuffers;
  void check_material(size_t material) const;
  void decode_opencl_into(size_t n, const QuerySource& query, Rgb* out) const;
  DeviceBuffers& device_buffers() const;

  const Database& db_;
  // Flattened views of the code-books, so the inner loop does no bounds or size look-ups.
  int nb_, na_;
  std::vector<double> beta_nodes_;
  const float* p1_;
  const float* c_;
  const uint32_t* i1_;
  const uint32_t* i2_;
  const uint32_t* p2_index_;
  const float* p2_scale_;
  const uint32_t* m_;
  const uint32_t* p3_index_;
  const float* p3_scale_;
  const uint32_t* p4_index_;
  const float* p4_scale_;
  size_t nt_, np_;

  mutable std::mutex device_mutex_;
  mutable std::mutex batch_mutex_;  // one batch at a time uses the device buffers' query buffers
  mutable std::unique_ptr<DeviceBuffers> device_;
};

}  // namespace btfvq
