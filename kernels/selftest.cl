// A trivial kernel that proves the device compiles and runs embedded sources: y = a * x + y.
__kernel void saxpy(const float a, __global const float* x, __global float* y, const uint n) {
  const uint i = get_global_id(0);
  if (i < n) y[i] = a * x[i] + y[i];
}
