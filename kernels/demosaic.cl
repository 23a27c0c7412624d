// The demosaic stage (include/qdo/physics/demosaic.hpp): one Bayer raw plane -> R, G, B planes, bilinear or
// Malvar-He-Cutler (5 x 5, gradient-corrected), and its transpose. Both are linear: output (c, y, x)
// = sum of w * raw(m(y + dy), m(x + dx)) over the 5 x 5 filter picked by the pixel's site and c,
// m the mirror about the edge pixel (m(-1) = 1, m(H) = H - 2; keeps parity, so the mosaic).
// CPU reference: ref::demosaic, ref::demosaic_vjp (demosaic_reference.hpp), which spells the same
// filters as tap lists from the formulas.

// Filters in sixteenths (the transpose reads them; the forward spells the same sums out),
// [method][filter][(dy + 2) * 5 + dx + 2]; method 0 bilinear, 1 MHC;
// filter 0 identity, 1 cross (G at R or B), 2 horizontal (the colour lies left and right),
// 3 vertical (above and below), 4 diagonal (R at B, B at R). Every filter sums to 16.
__constant int DEMOSAIC_W16[2][5][25] = {
    {{0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 16, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
     {0, 0, 0, 0, 0, 0, 0, 4, 0, 0, 0, 4, 0, 4, 0, 0, 0, 4, 0, 0, 0, 0, 0, 0, 0},
     {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 8, 0, 8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
     {0, 0, 0, 0, 0, 0, 0, 8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 8, 0, 0, 0, 0, 0, 0, 0},
     {0, 0, 0, 0, 0, 0, 4, 0, 4, 0, 0, 0, 0, 0, 0, 0, 4, 0, 4, 0, 0, 0, 0, 0, 0}},
    {{0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 16, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
     {0, 0, -2, 0, 0, 0, 0, 4, 0, 0, -2, 4, 8, 4, -2, 0, 0, 4, 0, 0, 0, 0, -2, 0, 0},
     {0, 0, 1, 0, 0, 0, -2, 0, -2, 0, -2, 8, 10, 8, -2, 0, -2, 0, -2, 0, 0, 0, 1, 0, 0},
     {0, 0, -2, 0, 0, 0, -2, 8, -2, 0, 1, 0, 10, 0, 1, 0, -2, 8, -2, 0, 0, 0, -2, 0, 0},
     {0, 0, -3, 0, 0, 0, 4, 0, 4, 0, -3, 0, 12, 0, -3, 0, 4, 0, 4, 0, 0, 0, -3, 0, 0}}};

// The filter for output channel c (0 R, 1 G, 2 B) at a site: [site class][c]; classes 0 an R site,
// 1 a B site, 2 a G site with R left and right, 3 a G site with R above and below.
__constant int DEMOSAIC_SELECT[4][3] = {{0, 1, 4}, {4, 1, 0}, {2, 0, 3}, {3, 0, 2}};

// The 13 offsets (dy, dx) where some filter has a non-zero tap: the centre, the axes to 2 pixels,
// the four diagonal neighbours.
__constant int DEMOSAIC_TAPS[13][2] = {{0, 0},  {-1, 0}, {1, 0},  {0, -1},  {0, 1},  {-2, 0}, {2, 0},
                                       {0, -2}, {0, 2},  {-1, -1}, {-1, 1}, {1, -1}, {1, 1}};

// The channel filtered at (y, x): cfa_code holds the 2 x 2 cell, two bits per entry (y & 1) * 2 + (x & 1).
inline int demosaic_channel(int cfa_code, int y, int x) { return (cfa_code >> (2 * ((y & 1) * 2 + (x & 1)))) & 3; }

inline int demosaic_class(int cfa_code, int y, int x) {
  const int s = demosaic_channel(cfa_code, y, x);
  if (s == 0) return 0;
  if (s == 2) return 1;
  return demosaic_channel(cfa_code, y, x ^ 1) == 0 ? 2 : 3;
}

// Mirror about the edge pixel without repeat; n >= 3 and i within 2 of [0, n).
inline int demosaic_mirror(int i, int n) {
  i = i < 0 ? -i : i;
  return i >= n ? 2 * (n - 1) - i : i;
}

// Forward. raw: scenes x rows x cols reals (one plane per scene, linear units), rgb: scenes x 3 x
// rows x cols; one work item per pixel (k, y, x) writes its three channels. method 0 bilinear, 1 MHC.
// The 13 taps the filters read are loaded once and the four interpolating filters of the table
// above are evaluated as sums (the same sixteenths), then selected by the site: no branch on the
// site, so the work-group loop vectorises.
__kernel void demosaic_forward(__global const real* raw, __global real* rgb, const int rows, const int cols,
                               const int cfa_code, const int method, const int scenes) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)rows * cols;
  if (gid >= hw * scenes) return;
  const int k = (int)(gid / hw);
  const int p = (int)(gid - (size_t)k * hw);
  const int y = p / cols, x = p - (p / cols) * cols;
  __global const real* plane = raw + (size_t)k * hw;
  const size_t ym2 = (size_t)demosaic_mirror(y - 2, rows) * cols, ym1 = (size_t)demosaic_mirror(y - 1, rows) * cols,
               y0 = (size_t)y * cols, yp1 = (size_t)demosaic_mirror(y + 1, rows) * cols,
               yp2 = (size_t)demosaic_mirror(y + 2, rows) * cols;
  const int xm2 = demosaic_mirror(x - 2, cols), xm1 = demosaic_mirror(x - 1, cols), xp1 = demosaic_mirror(x + 1, cols),
            xp2 = demosaic_mirror(x + 2, cols);
  const real c0 = plane[y0 + x];
  const real n1 = plane[ym1 + x], s1 = plane[yp1 + x], w1 = plane[y0 + xm1], e1 = plane[y0 + xp1];
  const real n2 = plane[ym2 + x], s2 = plane[yp2 + x], w2 = plane[y0 + xm2], e2 = plane[y0 + xp2];
  const real dsum = plane[ym1 + xm1] + plane[ym1 + xp1] + plane[yp1 + xm1] + plane[yp1 + xp1];
  real cross, horiz, vert, diag;
  if (method == 0) {
    cross = R(4.0) * (n1 + s1 + w1 + e1);
    horiz = R(8.0) * (w1 + e1);
    vert = R(8.0) * (n1 + s1);
    diag = R(4.0) * dsum;
  } else {
    const real ns2 = n2 + s2, we2 = w2 + e2;
    cross = R(8.0) * c0 + R(4.0) * (n1 + s1 + w1 + e1) - R(2.0) * (ns2 + we2);
    horiz = R(10.0) * c0 + R(8.0) * (w1 + e1) - R(2.0) * we2 - R(2.0) * dsum + ns2;
    vert = R(10.0) * c0 + R(8.0) * (n1 + s1) - R(2.0) * ns2 - R(2.0) * dsum + we2;
    diag = R(12.0) * c0 + R(4.0) * dsum - R(3.0) * (ns2 + we2);
  }
  const real own = R(16.0) * c0;
  const int cls = demosaic_class(cfa_code, y, x);
  // DEMOSAIC_SELECT spelled out: R site (own, cross, diag), B site (diag, cross, own), G with R left
  // and right (horiz, own, vert), G with R above and below (vert, own, horiz).
  const real r = cls == 0 ? own : cls == 1 ? diag : cls == 2 ? horiz : vert;
  const real g = cls <= 1 ? cross : own;
  const real b = cls == 0 ? diag : cls == 1 ? own : cls == 2 ? vert : horiz;
  rgb[((size_t)k * 3 + 0) * hw + p] = r * R(0.0625);
  rgb[((size_t)k * 3 + 1) * hw + p] = g * R(0.0625);
  rgb[((size_t)k * 3 + 2) * hw + p] = b * R(0.0625);
}

// Transpose. g_rgb: scenes x 3 x rows x cols, g_raw: scenes x rows x cols, written whole; one work
// item per raw pixel q = (k, y, x) gathers w * g_rgb(c, p) over every output p and tap d whose read
// m(p + d) lands on q: p + d is q itself or one of its mirror images (-q, 2 (n - 1) - q per axis).
__kernel void demosaic_adjoint(__global const real* g_rgb, __global real* g_raw, const int rows, const int cols,
                               const int cfa_code, const int method, const int scenes) {
  const size_t gid = get_global_id(0);
  const size_t hw = (size_t)rows * cols;
  if (gid >= hw * scenes) return;
  const int k = (int)(gid / hw);
  const int q = (int)(gid - (size_t)k * hw);
  const int y = q / cols, x = q - (q / cols) * cols;
  int ey[3], ex[3];
  int ny = 0, nx = 0;
  ey[ny++] = y;
  if (y > 0 && y <= 2) ey[ny++] = -y;
  if (y < rows - 1 && y >= rows - 3) ey[ny++] = 2 * (rows - 1) - y;
  ex[nx++] = x;
  if (x > 0 && x <= 2) ex[nx++] = -x;
  if (x < cols - 1 && x >= cols - 3) ex[nx++] = 2 * (cols - 1) - x;
  __global const real* g = g_rgb + (size_t)k * 3 * hw;
  // The site class of each parity (the mosaic repeats every 2 pixels).
  int cls_of[4];
  for (int i = 0; i < 4; ++i) cls_of[i] = demosaic_class(cfa_code, i >> 1, i & 1);
  real s = R(0.0);
  for (int a = 0; a < ny; ++a)
    for (int b = 0; b < nx; ++b)
      for (int t = 0; t < 13; ++t) {  // the taps any filter has (the other 12 of the 5 x 5 are 0 in all)
        const int dy = DEMOSAIC_TAPS[t][0], dx = DEMOSAIC_TAPS[t][1];
        const int py = ey[a] - dy, px = ex[b] - dx;
        if (py < 0 || py >= rows || px < 0 || px >= cols) continue;
        const int cls = cls_of[(py & 1) * 2 + (px & 1)];
        const int ti = (dy + 2) * 5 + dx + 2;
        const size_t pp = (size_t)py * cols + px;
        for (int c = 0; c < 3; ++c) s += (real)DEMOSAIC_W16[method][DEMOSAIC_SELECT[cls][c]][ti] * g[(size_t)c * hw + pp];
      }
  g_raw[gid] = s * R(0.0625);
}
