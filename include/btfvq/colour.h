#pragma once
// Colour spaces in which luminance and chroma are coded separately (paper Sec. 4.3):
//  - LDR: BT.601 studio-swing YCbCr computed on the gamma-encoded 8-bit values, exactly the
//    constants of the original decoder (docs/btfbase-format.md step 5). Y in [16, 235], Cb/Cr in [16, 240].
//  - HDR: LogLuv (Larson 1998): log2 luminance and CIE 1976 (u', v') chromaticity of linear
//    Rec. 709 RGB. The coding space keeps luminance linear (L = Y) because MLVQ normalises luminance
//    slices into densities, which must be non-negative; u', v' are scaled by 255 so that chroma
//    thresholds mean the same in both spaces.
namespace btfvq {

struct Rgb {
  float r = 0, g = 0, b = 0;
};
struct YCbCr {
  float y = 0, cb = 0, cr = 0;
};
struct LogLuv {
  float log2_y = 0, u = 0, v = 0;
};
// A value in the coding space: luminance L and two chroma channels a, b.
struct Lab3 {
  float l = 0, a = 0, b = 0;
};

YCbCr rgb_to_ycbcr(const Rgb& rgb);
// The original decoder's inverse; clamps below at 0 only (not above), as docs/btfbase-format.md step 5.
Rgb ycbcr_to_rgb(const YCbCr& ycc);

LogLuv rgb_to_logluv(const Rgb& linear_rgb);
Rgb logluv_to_rgb(const LogLuv& luv);

// Coding space used by the encoder and decoder for a sample of the given dynamic range.
Lab3 to_coding_space(const Rgb& rgb, bool hdr);
Rgb from_coding_space(const Lab3& lab, bool hdr);

// BT.601 luma of gamma-encoded RGB (0..255), the channel MSSIM is computed on.
inline float bt601_luma(const Rgb& c) { return 0.299f * c.r + 0.587f * c.g + 0.114f * c.b; }

}  // namespace btfvq
