// 3DGS's photometric loss and its gradient (Kerbl et al. 2023, eq. 7): (1 - lambda) L1 +
// lambda (1 - SSIM), L1 the mean absolute difference over pixels and channels, SSIM the mean of
// the SSIM map with an 11x11 Gaussian window of sigma 1.5 and zero padding (the reference
// trainer's utils/loss_utils.py: conv2d with padding 5), C1 = 0.01^2, C2 = 0.03^2.
#ifndef HVDB_INGEST_GAUSSIAN_LOSS_H_
#define HVDB_INGEST_GAUSSIAN_LOSS_H_

#include <cstddef>
#include <vector>

namespace hvdb::ingest {

struct PhotoLoss {
  double loss = 0, l1 = 0, ssim = 0;
};

// The loss of `render` against `target` (each width * height * 3 floats, row-major RGB), and
// when `grad` is not null dLoss/drender into it (resized). Convolutions on up to `threads`
// threads.
PhotoLoss L1DssimLoss(const std::vector<float>& render, const std::vector<float>& target, int width,
                      int height, float lambda, unsigned threads, std::vector<float>* grad);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_GAUSSIAN_LOSS_H_
