/* The C header used from C. Two modes:
 *   c_api_test BTFBASE_DIR
 *     opens the original compressor's proposte database and checks the known decoded values of
 *     docs/btfbase-format.md (to 0.05), the error codes and sample/pdf agreement;
 *   c_api_test DB MATERIAL U V THETA_I PHI_I THETA_V PHI_V R G B XI1 XI2 LX LY LZ PDF
 *     asserts that the C API gives exactly the RGB, sampled direction and pdf the C++ API gave
 *     (tests/test_c_api.cpp runs it with the C++ values). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <btfvq/btfvq_c.h>

static int failures = 0;

#define EXPECT(cond)                                                         \
  do {                                                                       \
    if (!(cond)) {                                                           \
      fprintf(stderr, "%s:%d: failed: %s (last error: %s)\n", __FILE__, __LINE__, #cond, btfvq_last_error()); \
      ++failures;                                                            \
    }                                                                        \
  } while (0)

static btfvq_vec3 vector_of(double theta, double phi) {
  const double d = 3.14159265358979323846 / 180.0;
  btfvq_vec3 v;
  v.x = cos(phi * d) * sin(theta * d);
  v.y = sin(phi * d) * sin(theta * d);
  v.z = cos(theta * d);
  return v;
}

static int known_values(const char* dir) {
  /* docs/btfbase-format.md, proposte: x, y, light (theta, phi), view (theta, phi), R, G, B. */
  static const double rows[5][9] = {
      {0, 0, 0, 0, 0, 0, 233.31, 209.99, 175.31},
      {10, 20, 60, 90, 0, 0, 141.91, 127.94, 108.17},
      {33, 7, 45, 120, 30, 60, 205.27, 192.56, 174.63},
      {5, 40, 75, 345, 75, 15, 179.94, 167.17, 149.14},
      {63, 63, 15, 300, 60, 240, 227.56, 199.34, 159.10},
  };
  btfvq_database* db = NULL;
  btfvq_material* mat = NULL;
  const char* name = NULL;
  size_t count = 0;
  int w = 0, h = 0, hdr = -1, i;
  float rgb[3];
  btfvq_vec3 light;
  double pdf = 0, pdf2 = 0;

  EXPECT(btfvq_open("/nonexistent/none.btfdb", &db) == BTFVQ_INVALID_ARGUMENT);
  EXPECT(db == NULL && strlen(btfvq_last_error()) > 0);
  EXPECT(btfvq_open(NULL, &db) == BTFVQ_INVALID_ARGUMENT);

  EXPECT(btfvq_open(dir, &db) == BTFVQ_OK);
  if (!db) return 1;
  EXPECT(strcmp(btfvq_last_error(), "") == 0);
  EXPECT(btfvq_material_count(db, &count) == BTFVQ_OK && count == 1);
  EXPECT(btfvq_material_name(db, 0, &name) == BTFVQ_OK && strcmp(name, "proposte") == 0);
  EXPECT(btfvq_material_name(db, 1, &name) == BTFVQ_NOT_FOUND);
  EXPECT(btfvq_find_material(db, "nope", &mat) == BTFVQ_NOT_FOUND && mat == NULL);
  EXPECT(strstr(btfvq_last_error(), "nope") != NULL);
  EXPECT(strcmp(btfvq_status_name(BTFVQ_NOT_FOUND), "not_found") == 0);
  EXPECT(btfvq_find_material(db, "proposte", &mat) == BTFVQ_OK);
  if (!mat) return 1;
  btfvq_close(db); /* the material keeps the database alive */
  EXPECT(btfvq_material_size(mat, &w, &h, &hdr) == BTFVQ_OK && w == 256 && h == 256 && hdr == 0);
  EXPECT(btfvq_evaluate(mat, 0, 0, vector_of(0, 0), vector_of(0, 0), NULL) == BTFVQ_INVALID_ARGUMENT);

  for (i = 0; i < 5; ++i) {
    const double* r = rows[i];
    const double u = (r[0] + 0.5) / w, v = (r[1] + 0.5) / h;
    EXPECT(btfvq_evaluate_angles(mat, u, v, r[2], r[3], r[4], r[5], rgb) == BTFVQ_OK);
    EXPECT(fabs(rgb[0] - r[6]) < 0.05 && fabs(rgb[1] - r[7]) < 0.05 && fabs(rgb[2] - r[8]) < 0.05);
    EXPECT(btfvq_evaluate(mat, u, v, vector_of(r[2], r[3]), vector_of(r[4], r[5]), rgb) == BTFVQ_OK);
    EXPECT(fabs(rgb[0] - r[6]) < 0.05 && fabs(rgb[1] - r[7]) < 0.05 && fabs(rgb[2] - r[8]) < 0.05);
  }
  for (i = 0; i < 100; ++i) {
    const btfvq_vec3 view = vector_of(0.8 * i, 3.7 * i);
    EXPECT(btfvq_sample(mat, 0.01 * i, 0.3, view, 0.01 * i, 1.0 - 0.01 * i, &light, &pdf) == BTFVQ_OK);
    EXPECT(light.z >= 0 && pdf > 0);
    EXPECT(btfvq_pdf(mat, 0.01 * i, 0.3, light, view, &pdf2) == BTFVQ_OK);
    EXPECT(fabs(pdf2 / pdf - 1.0) < 1e-9);
    if (fabs(pdf2 / pdf - 1.0) >= 1e-9) fprintf(stderr, "i %d pdf %.17g pdf() %.17g light %g %g %g\n", i, pdf, pdf2, light.x, light.y, light.z);
  }
  EXPECT(btfvq_albedo(mat, 0.5, 0.5, vector_of(30, 60), rgb) == BTFVQ_OK && rgb[1] > 0);
  btfvq_release_material(mat);
  btfvq_release_material(NULL);
  btfvq_close(NULL);
  return failures ? 1 : 0;
}

static int same_as_cpp(char** a) {
  btfvq_database* db = NULL;
  btfvq_material* mat = NULL;
  float rgb[3];
  btfvq_vec3 light;
  double pdf = 0;
  const double u = atof(a[3]), v = atof(a[4]);
  const btfvq_vec3 l = vector_of(atof(a[5]), atof(a[6])), view = vector_of(atof(a[7]), atof(a[8]));
  EXPECT(btfvq_open(a[1], &db) == BTFVQ_OK);
  if (!db) return 1;
  EXPECT(btfvq_find_material(db, a[2], &mat) == BTFVQ_OK);
  if (!mat) return 1;
  EXPECT(btfvq_evaluate(mat, u, v, l, view, rgb) == BTFVQ_OK);
  /* Exactly equal: the C++ side printed the floats with 9 significant digits (round-trip exact). */
  EXPECT(rgb[0] == strtof(a[9], NULL) && rgb[1] == strtof(a[10], NULL) && rgb[2] == strtof(a[11], NULL));
  EXPECT(btfvq_sample(mat, u, v, view, atof(a[12]), atof(a[13]), &light, &pdf) == BTFVQ_OK);
  EXPECT(light.x == strtod(a[14], NULL) && light.y == strtod(a[15], NULL) && light.z == strtod(a[16], NULL));
  EXPECT(pdf == strtod(a[17], NULL));
  if (failures) fprintf(stderr, "C: rgb %.9g %.9g %.9g pdf %.17g\n", rgb[0], rgb[1], rgb[2], pdf);
  btfvq_release_material(mat);
  btfvq_close(db);
  return failures ? 1 : 0;
}

int main(int argc, char** argv) {
  if (argc == 2) return known_values(argv[1]);
  if (argc == 18) return same_as_cpp(argv);
  fprintf(stderr, "usage: c_api_test BTFBASE_DIR | DB MATERIAL U V TI PI TV PV R G B XI1 XI2 LX LY LZ PDF\n");
  return 2;
}
