// Real spherical harmonics, degree 0 to 4: degrees 0-3 with the basis and constants of the
// original 3DGS code, degree 4 in the same sign convention (the one gsplat evaluates); sh[n, k, c]
// layout, see docs/conventions.md "Gaussians".
#pragma once

#include <algorithm>

namespace cs {

constexpr double kShC0 = 0.28209479177387814;
constexpr double kShC1 = 0.4886025119029199;
constexpr double kShC2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                           -1.0925484305920792, 0.5462742152960396};
constexpr double kShC3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                           0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                           -0.5900435899266435};
// Degree 4, as factors of the polynomials below (m = -4 ... 4).
constexpr double kShC4[9] = {2.5033429417967046, -1.7701307697799304, 0.9461746957575601,
                           -0.6690465435572892, 0.10578554691520431, -0.6690465435572892,
                           0.47308734787878004, -1.7701307697799304, 0.6258357354491763};

// max(0, SH(d) + 0.5) per channel for the coefficients (k, 3) of one Gaussian; d is a unit
// direction (mean - camera centre). k in {1, 4, 9, 16, 25}.
inline void sh_to_rgb(const float* coeffs, int k, const double d[3], float out[3]) {
    if (k == 1) {  // the common view-independent case
        for (int c = 0; c < 3; ++c) out[c] = float(std::max(0.0, kShC0 * double(coeffs[c]) + 0.5));
        return;
    }
    double basis[25];
    basis[0] = kShC0;
    if (k > 1) {
        const double x = d[0], y = d[1], z = d[2];
        basis[1] = -kShC1 * y;
        basis[2] = kShC1 * z;
        basis[3] = -kShC1 * x;
        if (k > 4) {
            const double xx = x * x, yy = y * y, zz = z * z;
            basis[4] = kShC2[0] * x * y;
            basis[5] = kShC2[1] * y * z;
            basis[6] = kShC2[2] * (2.0 * zz - xx - yy);
            basis[7] = kShC2[3] * x * z;
            basis[8] = kShC2[4] * (xx - yy);
            if (k > 9) {
                basis[9] = kShC3[0] * y * (3.0 * xx - yy);
                basis[10] = kShC3[1] * x * y * z;
                basis[11] = kShC3[2] * y * (4.0 * zz - xx - yy);
                basis[12] = kShC3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
                basis[13] = kShC3[4] * x * (4.0 * zz - xx - yy);
                basis[14] = kShC3[5] * z * (xx - yy);
                basis[15] = kShC3[6] * x * (xx - 3.0 * yy);
                if (k > 16) {
                    const double xy = x * y, xz = x * z, yz = y * z, z7 = 7.0 * zz;
                    basis[16] = kShC4[0] * xy * (xx - yy);
                    basis[17] = kShC4[1] * yz * (3.0 * xx - yy);
                    basis[18] = kShC4[2] * xy * (z7 - 1.0);
                    basis[19] = kShC4[3] * yz * (z7 - 3.0);
                    basis[20] = kShC4[4] * (zz * (35.0 * zz - 30.0) + 3.0);
                    basis[21] = kShC4[5] * xz * (z7 - 3.0);
                    basis[22] = kShC4[6] * (xx - yy) * (z7 - 1.0);
                    basis[23] = kShC4[7] * xz * (xx - 3.0 * yy);
                    basis[24] = kShC4[8] * (xx * (xx - 3.0 * yy) - yy * (3.0 * xx - yy));
                }
            }
        }
    }
    for (int c = 0; c < 3; ++c) {
        double acc = 0.0;
        for (int j = 0; j < k; ++j) acc += basis[j] * double(coeffs[3 * j + c]);
        out[c] = float(std::max(0.0, acc + 0.5));
    }
}

}  // namespace cs
