// Helpers the render job's files share (job.cc, job/texture.cc); not part of render/job.h.
#ifndef HVDB_RENDER_JOB_INTERNAL_H_
#define HVDB_RENDER_JOB_INTERNAL_H_

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "render/renderer.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::render::internal {

// A stored photo's bytes (PNG or JPEG) as 8-bit RGB of its camera's size; Corruption saying
// `what` otherwise (stored photos were checked when they were stored).
Result<std::vector<uint8_t>> DecodeRgb8(const std::string& bytes, uint32_t width, uint32_t height,
                                        const std::string& what);

// Prefixes a check's message with the request field it concerns.
Status InField(const std::string& field, const Status& st);

// The factor (1, 2 or 4) by which a source camera's depth is drawn smaller for texturing,
// from the size of the points' splats in that camera's own pixels (job/texture.cc says why).
uint32_t SourceDepthScale(std::span<const Point> points, const Camera& camera,
                          const RenderOptions& options);

}  // namespace hvdb::render::internal

#endif  // HVDB_RENDER_JOB_INTERNAL_H_
