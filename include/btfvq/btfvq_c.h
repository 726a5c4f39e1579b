/* The btfvq decode API in plain C (over include/btfvq/renderer_api.h), for renderers in any language.
 *
 * Handles are opaque; every function returns a status (BTFVQ_OK = 0) and never lets an exception
 * or a crash through for a bad argument; btfvq_last_error() gives the message of the last failure
 * on the calling thread. Database and material handles are immutable and may be used from any
 * number of threads at once; a material handle keeps its database alive (close both, in any order).
 *
 * Conventions (docs/sampling.md): (u, v) texture coordinates, the texel is (floor(u W), floor(v H))
 * wrapped; directions are vectors in the tangent frame (z = normal, x = tangent at azimuth 0),
 * or (theta, phi) in degrees in the same frame; RGB as the decoder returns it (gamma-encoded 0..255
 * for LDR, linear for HDR); pdf in solid-angle measure (1/sr).
 */
#ifndef BTFVQ_C_H
#define BTFVQ_C_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct btfvq_database btfvq_database;
typedef struct btfvq_material btfvq_material;

typedef struct btfvq_vec3 {
  double x, y, z;
} btfvq_vec3;

typedef enum btfvq_status {
  BTFVQ_OK = 0,
  BTFVQ_INVALID_ARGUMENT = 1, /* a null pointer, a bad file or value (the library's InputError) */
  BTFVQ_NOT_FOUND = 2,        /* no such material */
  BTFVQ_CORRUPT = 3,          /* the database file is damaged */
  BTFVQ_DEVICE = 4,           /* the compute device failed */
  BTFVQ_INTERNAL = 5          /* anything else (e.g. out of memory) */
} btfvq_status;

/* Message of the last failed call on this thread ("" if none); valid until the next call on it. */
const char* btfvq_last_error(void);
/* Stable name of a status, e.g. "not_found". */
const char* btfvq_status_name(btfvq_status status);

/* Opens a .btfdb file, or a BTFBASE directory of the original compressor, read-only. */
btfvq_status btfvq_open(const char* path, btfvq_database** out);
void btfvq_close(btfvq_database* db); /* null is allowed */

btfvq_status btfvq_material_count(const btfvq_database* db, size_t* count);
/* The name stays valid while `db` is open. */
btfvq_status btfvq_material_name(const btfvq_database* db, size_t index, const char** name);
btfvq_status btfvq_find_material(const btfvq_database* db, const char* name, btfvq_material** out);
void btfvq_release_material(btfvq_material* material); /* null is allowed */
btfvq_status btfvq_material_size(const btfvq_material* material, int* width, int* height, int* hdr);

/* RGB of the BTF at (u, v) for a light and a view. */
btfvq_status btfvq_evaluate(const btfvq_material* material, double u, double v, btfvq_vec3 light, btfvq_vec3 view,
                            float rgb[3]);
/* The same with directions as (theta, phi) in degrees. */
btfvq_status btfvq_evaluate_angles(const btfvq_material* material, double u, double v, double theta_i, double phi_i,
                                   double theta_v, double phi_v, float rgb[3]);
/* A light direction for `view` from two uniform numbers in [0, 1] (importance sampling, paper Sec. 5.2). */
btfvq_status btfvq_sample(const btfvq_material* material, double u, double v, btfvq_vec3 view, double xi1, double xi2,
                          btfvq_vec3* light, double* pdf);
/* The density btfvq_sample draws `light` with. */
btfvq_status btfvq_pdf(const btfvq_material* material, double u, double v, btfvq_vec3 light, btfvq_vec3 view,
                       double* pdf);
/* Integral over the lights of evaluate x cos(theta_i) (paper eq. 6). */
btfvq_status btfvq_albedo(const btfvq_material* material, double u, double v, btfvq_vec3 view, float rgb[3]);

#ifdef __cplusplus
}
#endif

#endif /* BTFVQ_C_H */
