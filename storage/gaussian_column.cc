#include "storage/gaussian_column.h"

#include <algorithm>
#include <bit>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <numeric>
#include <set>

#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/gaussian_sh.h"

namespace hvdb {
namespace {

constexpr char kSegmentMagic[8] = {'H', 'V', 'D', 'B', 'G', 'S', 'C', '\0'};
constexpr uint32_t kSegmentVersion = 1;
constexpr size_t kSegmentHeaderSize = 64;
constexpr uint32_t kBlockRecords = 1024;
constexpr uint64_t kMaxSegmentRecords = uint64_t{1} << 32;

std::string SegmentName(uint64_t first_id) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%016" PRIx64 ".gsc", first_id);
  return buf;
}

bool ParseSegmentName(const std::string& name, uint64_t* first_id) {
  if (name.size() != 20 || !name.ends_with(".gsc")) return false;
  uint64_t v = 0;
  for (size_t i = 0; i < 16; ++i) {
    const char c = name[i];
    const int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
    if (d < 0) return false;
    v = v << 4 | static_cast<uint64_t>(d);
  }
  *first_id = v;
  return true;
}

std::string Hex(uint64_t v) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "%" PRIu64, v);
  return buf;
}

}  // namespace

void DeriveGaussian(const Point& p, float* rec) {
  std::fill(rec, rec + GaussianRecordFloats(0), 0.f);
  double cov[3][3];
  if (p.flags & kFlagHasCovariance) {
    const auto& c = p.cov;
    const double m[3][3] = {{c[0], c[1], c[2]}, {c[1], c[3], c[4]}, {c[2], c[4], c[5]}};
    std::memcpy(cov, m, sizeof cov);
  } else {
    const double s2 = 1e-6;  // 1 mm: a point with no footprint of its own
    const double m[3][3] = {{s2, 0, 0}, {0, s2, 0}, {0, 0, s2}};
    std::memcpy(cov, m, sizeof cov);
  }
  Mat3d m;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m[3 * i + j] = cov[i][j];
  }
  std::array<double, 3> ev;
  Mat3d v;
  SymmetricEigen3(m, &ev, &v);
  for (int i = 0; i < 3; ++i) {
    rec[kGsScale + i] = static_cast<float>(0.5 * std::log(std::max(ev[i], 1e-20)));
  }
  // The quaternion of the rotation whose columns are the eigenvectors.
  const std::array<double, 4> q = QuaternionOf(v);
  for (int k = 0; k < 4; ++k) rec[kGsRotation + k] = static_cast<float>(q[k]);
  rec[kGsOpacity] = static_cast<float>(std::log(0.99 / 0.01));
  const uint8_t rgb[3] = {p.r, p.g, p.b};
  for (int c = 0; c < 3; ++c) rec[kGsDc + c] = static_cast<float>((rgb[c] / 255.0 - 0.5) / kShC0);
}

void WidenRecord(const float* src, int from, float* dst, int to) {
  const size_t rest_src = GaussianRecordFloats(from) - kGsRest;
  const size_t rest_dst = GaussianRecordFloats(to) - kGsRest;
  std::copy(src, src + kGsRest, dst);
  std::fill(dst + kGsRest, dst + kGsRest + rest_dst, 0.f);
  for (size_t ch = 0; ch < 3; ++ch) {
    std::copy_n(src + kGsRest + ch * rest_src / 3, rest_src / 3, dst + kGsRest + ch * rest_dst / 3);
  }
}

uint64_t DeriveMissing(std::span<const Point> points, const std::vector<bool>& found,
                       GaussianColumns* cols) {
  const size_t stride = cols->stride();
  cols->values.resize(points.size() * stride, 0.f);
  uint64_t n = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    if (i < found.size() && found[i]) continue;
    float* rec = cols->record(i);
    std::fill(rec, rec + stride, 0.f);
    DeriveGaussian(points[i], rec);
    ++n;
  }
  return n;
}

std::array<float, 6> GaussianCovariance(const float* rec) {
  const Mat3d r = RotationOf({rec[kGsRotation], rec[kGsRotation + 1], rec[kGsRotation + 2],
                              rec[kGsRotation + 3]});
  auto R = [&](int i, int j) { return r[3 * i + j]; };
  double s2[3];
  for (int i = 0; i < 3; ++i) s2[i] = std::exp(2.0 * rec[kGsScale + i]);
  auto c = [&](int i, int j) {
    return static_cast<float>(R(i, 0) * R(j, 0) * s2[0] + R(i, 1) * R(j, 1) * s2[1] +
                              R(i, 2) * R(j, 2) * s2[2]);
  };
  return {c(0, 0), c(0, 1), c(0, 2), c(1, 1), c(1, 2), c(2, 2)};
}

GaussianRecordMap::GaussianRecordMap(const std::array<double, 9>& a) : a_(a) {
  identity_ = a == Mat3d{1, 0, 0, 0, 1, 0, 0, 0, 1};
  // A^T A = k^2 I for a similarity; else its eigen-decomposition gives A's polar factor.
  Mat3d ata{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      for (int k = 0; k < 3; ++k) ata[3 * i + j] += a[3 * k + i] * a[3 * k + j];
    }
  }
  const double k2 = (ata[0] + ata[4] + ata[8]) / 3;
  double off = 0;
  for (int i = 0; i < 9; ++i) off = std::max(off, std::fabs(ata[i] - (i % 4 == 0 ? k2 : 0)));
  similarity_ = off <= 1e-9 * k2;
  mirror_ = Det3(a) < 0;
  if (similarity_) {
    const double k = std::sqrt(k2);
    log_scale_ = k == 1 ? 0 : std::log(k);
    for (int i = 0; i < 9; ++i) orthogonal_[i] = a[i] / k;
    if (!mirror_) q_ = QuaternionOf(orthogonal_);
  } else {
    std::array<double, 3> lambda;
    Mat3d v;
    SymmetricEigen3(ata, &lambda, &v);
    Mat3d inv_sqrt{};  // (A^T A)^(-1/2) = V diag(lambda^(-1/2)) V^T
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < 3; ++k) {
          inv_sqrt[3 * i + j] += v[3 * i + k] * v[3 * j + k] / std::sqrt(lambda[k]);
        }
      }
    }
    orthogonal_ = Mul3(a, inv_sqrt);
  }
  for (int l = 1; l <= kMaxGaussianShDegree; ++l) sh_[l] = ShRotationMatrix(l, orthogonal_);
}

bool GaussianRecordMap::Apply(int degree, float* rec) const {
  if (identity_) return true;
  const size_t n = GaussianRecordFloats(degree);
  std::vector<float> out(rec, rec + n);
  const std::array<double, 4> q = {rec[kGsRotation], rec[kGsRotation + 1], rec[kGsRotation + 2],
                                   rec[kGsRotation + 3]};
  const double qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  std::array<double, 4> turned;
  if (similarity_ && !mirror_) {
    turned = QuaternionProduct(q_, q);  // keeps the stored quaternion's length
    if (log_scale_ != 0) {
      for (int i = 0; i < 3; ++i) out[kGsScale + i] = static_cast<float>(rec[kGsScale + i] + log_scale_);
    }
  } else if (similarity_) {
    // Q R is left-handed; with its first column negated it is a rotation of the same
    // covariance (the axes' scales are squared).
    Mat3d r = Mul3(orthogonal_, RotationOf(q));
    for (int k = 0; k < 3; ++k) r[3 * k] = -r[3 * k];
    turned = QuaternionOf(r);
    if (log_scale_ != 0) {
      for (int i = 0; i < 3; ++i) out[kGsScale + i] = static_cast<float>(rec[kGsScale + i] + log_scale_);
    }
  } else {
    const Mat3d r = RotationOf(q);
    double s2[3];
    for (int i = 0; i < 3; ++i) s2[i] = std::exp(2.0 * rec[kGsScale + i]);
    Mat3d sigma{};
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < 3; ++k) sigma[3 * i + j] += r[3 * i + k] * r[3 * j + k] * s2[k];
      }
    }
    Mat3d as = Mul3(a_, sigma), moved{};
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < 3; ++k) moved[3 * i + j] += as[3 * i + k] * a_[3 * j + k];
      }
    }
    std::array<double, 3> lambda;
    Mat3d v;
    SymmetricEigen3(moved, &lambda, &v);
    for (int i = 0; i < 3; ++i) {
      out[kGsScale + i] = static_cast<float>(0.5 * std::log(std::max(lambda[i], 1e-300)));
    }
    turned = QuaternionOf(v);
  }
  if (!(similarity_ && !mirror_)) {
    for (double& c : turned) c *= qn > 0 ? qn : 1;
  }
  for (int k = 0; k < 4; ++k) out[kGsRotation + k] = static_cast<float>(turned[k]);
  const size_t per_channel = (n - kGsRest) / 3;
  for (int l = 1, first = 0; l <= degree; first += 2 * l + 1, ++l) {
    const int dim = 2 * l + 1;
    const std::vector<double>& m = sh_[l];
    for (size_t ch = 0; ch < 3; ++ch) {
      const float* in = rec + kGsRest + ch * per_channel + first;
      float* o = out.data() + kGsRest + ch * per_channel + first;
      for (int j = 0; j < dim; ++j) {
        double sum = 0;
        for (int k = 0; k < dim; ++k) sum += m[j * dim + k] * in[k];
        o[j] = static_cast<float>(sum);
      }
    }
  }
  for (float v : out) {
    if (!std::isfinite(v)) return false;
  }
  std::copy(out.begin(), out.end(), rec);
  return true;
}

Status ValidateGaussianColumns(const GaussianColumns& cols) {
  if (cols.sh_degree < 0 || cols.sh_degree > kMaxGaussianShDegree) {
    return Status::InvalidArgument("Gaussian attributes: SH degree must be 0..3, got " +
                                   std::to_string(cols.sh_degree));
  }
  const size_t stride = cols.stride();
  if (cols.values.size() % stride != 0) {
    return Status::InvalidArgument("Gaussian attributes: " + std::to_string(cols.values.size()) +
                                   " values are not whole records of " + std::to_string(stride));
  }
  // Branch-free first (a million splats hold 59 million values), then the place of the first.
  uint32_t bad = 0;
  for (float v : cols.values) bad |= (std::bit_cast<uint32_t>(v) & 0x7f800000u) == 0x7f800000u;
  if (bad == 0) return Status::OK();
  for (size_t i = 0; i < cols.values.size(); ++i) {
    if (!std::isfinite(cols.values[i])) {
      return Status::InvalidArgument("Gaussian attributes: splat " + std::to_string(i / stride) +
                                     ": value " + std::to_string(i % stride) + " is not finite");
    }
  }
  return Status::OK();
}

struct GaussianColumn::Segment {
  std::string path;
  std::shared_ptr<RandomAccessFile> file;
  uint64_t first_id = 0, count = 0;
  int degree = 0;
  bool antialiased = false;
  std::vector<uint32_t> crcs;  // masked, per block of kBlockRecords records
  size_t record_bytes() const { return 4 * GaussianRecordFloats(degree); }
};

Result<std::unique_ptr<GaussianColumn>> GaussianColumn::Open(Env* env,
                                                             const std::string& dataset_dir,
                                                             bool writer, uint64_t next_id) {
  const std::string dir = dataset_dir + "/gaussians";
  if (writer && !env->Exists(dir)) {
    // Its name made durable before any segment in it is relied on.
    HVDB_RETURN_IF_ERROR(env->CreateDirs(dir));
    HVDB_RETURN_IF_ERROR(env->SyncDir(dataset_dir));
  }
  std::unique_ptr<GaussianColumn> col(new GaussianColumn(env, dir));
  if (writer) {
    HVDB_RETURN_IF_ERROR(col->Recover(next_id));
  } else {
    HVDB_RETURN_IF_ERROR(col->Refresh());
  }
  return col;
}

Status GaussianColumn::Recover(uint64_t next_id) {
  writer_ = true;
  if (!env_->Exists(dir_)) return Status::OK();
  HVDB_ASSIGN_OR_RETURN(auto names, env_->ListDir(dir_));
  for (const std::string& name : names) {
    uint64_t first = 0;
    if (!ParseSegmentName(name, &first) || first >= next_id) {
      // A temporary file, or the segment of a load cut short: its ids were never issued.
      {
        std::lock_guard<std::mutex> lk(mu_);
        segments_.erase(first);
      }
      HVDB_RETURN_IF_ERROR(env_->Remove(dir_ + "/" + name));
    }
  }
  return Refresh();
}

Status GaussianColumn::Refresh() {
  if (!env_->Exists(dir_)) return Status::OK();
  HVDB_ASSIGN_OR_RETURN(auto names, env_->ListDir(dir_));
  std::set<uint64_t> present;
  std::vector<std::string> problems;
  for (const std::string& name : names) {
    uint64_t first = 0;
    if (!ParseSegmentName(name, &first)) continue;
    present.insert(first);
    {
      std::lock_guard<std::mutex> lk(mu_);
      if (segments_.count(first)) continue;
    }
    auto s = OpenSegment(name);
    if (!s.ok()) {
      if (!env_->Exists(dir_ + "/" + name)) continue;  // removed meanwhile
      // A damaged segment leaves the dataset open: its points read as derived Gaussians and
      // Check() names it.
      problems.push_back(s.status().ToString());
      continue;
    }
    std::lock_guard<std::mutex> lk(mu_);
    // Ranges may not overlap: a segment that does is reported, not used.
    auto next = segments_.lower_bound(first);
    const bool overlaps =
        (next != segments_.end() && next->first - first < (*s)->count) ||
        (next != segments_.begin() && first - std::prev(next)->first < std::prev(next)->second->count);
    if (overlaps) {
      problems.push_back(dir_ + "/" + name + ": its ids overlap another segment's; not used");
      continue;
    }
    segments_[first] = std::move(s).value();
  }
  std::lock_guard<std::mutex> lk(mu_);
  for (auto it = segments_.begin(); it != segments_.end();) {
    it = present.count(it->first) ? std::next(it) : segments_.erase(it);  // deleted by the writer
  }
  problems_ = std::move(problems);
  return Status::OK();
}

Result<std::shared_ptr<const GaussianColumn::Segment>> GaussianColumn::OpenSegment(
    const std::string& name) {
  auto s = std::make_shared<Segment>();
  s->path = dir_ + "/" + name;
  auto corrupt = [&](const std::string& m) { return Status::Corruption(s->path + ": " + m); };
  HVDB_ASSIGN_OR_RETURN(s->file, env_->OpenRead(s->path));
  if (s->file->size() < kSegmentHeaderSize + 4) return corrupt("truncated header");
  uint8_t h[kSegmentHeaderSize];
  HVDB_RETURN_IF_ERROR(s->file->Read(0, sizeof h, h));
  if (std::memcmp(h, kSegmentMagic, 8) != 0) return corrupt("bad magic");
  if (crc32c::Unmask(DecodeLE<uint32_t>(h + 60)) != crc32c::Value(h, 60)) {
    return corrupt("header checksum mismatch");
  }
  uint64_t named = 0;
  if (!ParseSegmentName(name, &named) || named != DecodeLE<uint64_t>(h + 24)) {
    return corrupt("its header's first id is not the one its name says");
  }
  if (DecodeLE<uint32_t>(h + 8) != kSegmentVersion) {
    return corrupt("unsupported version " + std::to_string(DecodeLE<uint32_t>(h + 8)));
  }
  const uint32_t degree = DecodeLE<uint32_t>(h + 12);
  const uint32_t flags = DecodeLE<uint32_t>(h + 16);
  const uint32_t block_records = DecodeLE<uint32_t>(h + 20);
  s->first_id = DecodeLE<uint64_t>(h + 24);
  s->count = DecodeLE<uint64_t>(h + 32);
  if (degree > kMaxGaussianShDegree || block_records != kBlockRecords ||
      s->count == 0 || s->count > kMaxSegmentRecords || s->first_id == 0) {
    return corrupt("bad header");
  }
  s->degree = static_cast<int>(degree);
  s->antialiased = (flags & 1) != 0;
  const uint64_t blocks = (s->count + kBlockRecords - 1) / kBlockRecords;
  const uint64_t table_at = kSegmentHeaderSize + s->count * s->record_bytes();
  if (s->file->size() != table_at + 4 * blocks + 4) {
    return corrupt("size " + std::to_string(s->file->size()) + " is not what its header says (" +
                   std::to_string(table_at + 4 * blocks + 4) + ")");
  }
  std::vector<uint8_t> table(4 * blocks + 4);
  HVDB_RETURN_IF_ERROR(s->file->Read(table_at, table.size(), table.data()));
  if (crc32c::Unmask(DecodeLE<uint32_t>(table.data() + 4 * blocks)) !=
      crc32c::Value(table.data(), 4 * blocks)) {
    return corrupt("checksum table mismatch");
  }
  s->crcs.resize(blocks);
  for (uint64_t b = 0; b < blocks; ++b) s->crcs[b] = DecodeLE<uint32_t>(table.data() + 4 * b);
  return std::shared_ptr<const Segment>(std::move(s));
}

Status GaussianColumn::Write(uint64_t first_id, const GaussianColumns& cols) {
  HVDB_RETURN_IF_ERROR(ValidateGaussianColumns(cols));
  const uint64_t n = cols.size();
  if (n == 0) return Status::OK();
  if (n > kMaxSegmentRecords) return Status::InvalidArgument("Gaussian attributes: too many splats");
  uint8_t h[kSegmentHeaderSize] = {};
  std::memcpy(h, kSegmentMagic, 8);
  EncodeLE<uint32_t>(h + 8, kSegmentVersion);
  EncodeLE<uint32_t>(h + 12, static_cast<uint32_t>(cols.sh_degree));
  EncodeLE<uint32_t>(h + 16, cols.antialiased ? 1u : 0u);
  EncodeLE<uint32_t>(h + 20, kBlockRecords);
  EncodeLE<uint64_t>(h + 24, first_id);
  EncodeLE<uint64_t>(h + 32, n);
  EncodeLE<uint32_t>(h + 60, crc32c::Mask(crc32c::Value(h, 60)));

  const std::string name = SegmentName(first_id);
  const std::string tmp = dir_ + "/" + name + ".tmp", path = dir_ + "/" + name;
  HVDB_ASSIGN_OR_RETURN(auto f, env_->OpenWrite(tmp, /*truncate=*/true));
  auto fail = [&](Status st) {
    f.reset();
    (void)env_->Remove(tmp);  // the error reported is the write's
    return st;
  };
  Status st = f->Append(std::string_view(reinterpret_cast<const char*>(h), sizeof h));
  if (!st.ok()) return fail(st);
  const size_t rb = 4 * cols.stride();
  std::string block, table;
  for (uint64_t b = 0; b * kBlockRecords < n; ++b) {
    const uint64_t lo = b * kBlockRecords, hi = std::min<uint64_t>(n, lo + kBlockRecords);
    block.resize((hi - lo) * rb);
    if constexpr (std::endian::native == std::endian::little) {
      std::memcpy(block.data(), cols.values.data() + lo * cols.stride(), block.size());
    } else {
      for (size_t k = 0; k < block.size() / 4; ++k) {
        EncodeLE<float>(reinterpret_cast<uint8_t*>(block.data()) + 4 * k,
                        cols.values[lo * cols.stride() + k]);
      }
    }
    uint8_t c[4];
    EncodeLE<uint32_t>(c, crc32c::Mask(crc32c::Value(block.data(), block.size())));
    table.append(reinterpret_cast<const char*>(c), 4);
    st = f->Append(block);
    if (!st.ok()) return fail(st);
  }
  uint8_t c[4];
  EncodeLE<uint32_t>(c, crc32c::Mask(crc32c::Value(table.data(), table.size())));
  table.append(reinterpret_cast<const char*>(c), 4);
  st = f->Append(table);
  if (st.ok()) st = f->Sync();
  if (!st.ok()) return fail(st);
  f.reset();
  st = env_->Rename(tmp, path);
  if (!st.ok()) return fail(st);
  HVDB_RETURN_IF_ERROR(env_->SyncDir(dir_));
  HVDB_ASSIGN_OR_RETURN(auto seg, OpenSegment(name));
  std::lock_guard<std::mutex> lk(mu_);
  segments_[first_id] = std::move(seg);
  return Status::OK();
}

Status GaussianColumn::Remove(uint64_t first_id) {
  // The file first: a refresh meanwhile then finds nothing to bring back.
  Status st = env_->Remove(dir_ + "/" + SegmentName(first_id));
  std::lock_guard<std::mutex> lk(mu_);
  segments_.erase(first_id);
  return st;
}

Status GaussianColumn::Read(std::span<const uint64_t> ids, GaussianColumns* out,
                            std::vector<bool>* found, size_t max_blocks) {
  // Resolve each id to its segment (an index into `segs`, -1: none); rescan once if some are
  // unknown (a follower's view).
  std::vector<std::shared_ptr<const Segment>> segs;
  std::vector<int32_t> seg_of(ids.size(), -1);
  auto resolve = [&]() {
    std::lock_guard<std::mutex> lk(mu_);
    bool missing = false;
    std::map<uint64_t, int32_t> index;  // segment first id -> position in segs
    for (size_t k = 0; k < segs.size(); ++k) index[segs[k]->first_id] = static_cast<int32_t>(k);
    // The ids of a frame are mostly one segment's: try the last one found first.
    const Segment* last = nullptr;
    int32_t last_index = -1;
    for (size_t i = 0; i < ids.size(); ++i) {
      if (seg_of[i] >= 0) continue;
      if (last != nullptr && ids[i] - last->first_id < last->count) {
        seg_of[i] = last_index;
        continue;
      }
      auto it = segments_.upper_bound(ids[i]);
      if (it != segments_.begin()) {
        --it;
        if (ids[i] - it->first < it->second->count) {
          auto [pos, added] = index.try_emplace(it->first, static_cast<int32_t>(segs.size()));
          if (added) segs.push_back(it->second);
          seg_of[i] = pos->second;
          last = it->second.get();
          last_index = pos->second;
          continue;
        }
      }
      missing = true;
    }
    return missing;
  };
  // A writer knows every segment; a follower may not have seen the writer's newest.
  if (resolve() && !writer_) {
    HVDB_RETURN_IF_ERROR(Refresh());
    resolve();
  }
  int degree = 0;
  out->antialiased = false;
  for (const auto& s : segs) {
    degree = std::max(degree, s->degree);
    out->antialiased = out->antialiased || s->antialiased;
  }
  out->sh_degree = degree;
  const size_t stride = GaussianRecordFloats(degree);
  out->values.resize(ids.size() * stride);
  found->assign(ids.size(), false);

  // Each needed block is read once, checked, and its records copied out: the ids of a query
  // come in tree order, so they are grouped by (segment, block) with a counting sort.
  // The ids by segment, once (a counting sort on seg_of), then each segment's by block.
  std::vector<uint32_t> seg_start(segs.size() + 1, 0);
  for (int32_t si : seg_of) {
    if (si >= 0) ++seg_start[static_cast<size_t>(si) + 1];
  }
  for (size_t si = 0; si < segs.size(); ++si) seg_start[si + 1] += seg_start[si];
  std::vector<uint32_t> by_seg(seg_start[segs.size()]);
  {
    std::vector<uint32_t> fill(seg_start.begin(), seg_start.end() - 1);
    for (size_t i = 0; i < ids.size(); ++i) {
      if (seg_of[i] >= 0) by_seg[fill[static_cast<size_t>(seg_of[i])]++] = static_cast<uint32_t>(i);
    }
  }
  // Reads are whole checked blocks (up to 236 KiB): ids spread over many blocks cost one each.
  size_t blocks_read = 0;
  std::vector<uint8_t> block;
  for (size_t si = 0; si < segs.size(); ++si) {
    const Segment& s = *segs[si];
    const size_t blocks = s.crcs.size();
    const std::span<const uint32_t> mine(by_seg.data() + seg_start[si],
                                         seg_start[si + 1] - seg_start[si]);
    std::vector<uint32_t> start(blocks + 1, 0);
    for (uint32_t i : mine) ++start[(ids[i] - s.first_id) / kBlockRecords + 1];
    for (size_t b = 0; b < blocks; ++b) {
      blocks_read += start[b + 1] > 0;
      start[b + 1] += start[b];
    }
    if (blocks_read > max_blocks) {
      return Status::LimitExceeded(
          "Gaussian records: the ids touch more than " + std::to_string(max_blocks) +
          " blocks of 1024 records; ask for fewer, or for ids in ascending runs");
    }
    std::vector<uint32_t> order(start[blocks]);
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    for (uint32_t i : mine) order[fill[(ids[i] - s.first_id) / kBlockRecords]++] = i;
    const size_t rb = s.record_bytes(), nf = rb / 4;
    const bool same = nf == stride && std::endian::native == std::endian::little;
    float decoded[GaussianRecordFloats(kMaxGaussianShDegree)];
    for (size_t b = 0; b < blocks; ++b) {
      if (start[b] == start[b + 1]) continue;
      const uint64_t lo = b * kBlockRecords, hi = std::min<uint64_t>(s.count, lo + kBlockRecords);
      block.resize((hi - lo) * rb);
      HVDB_RETURN_IF_ERROR(s.file->Read(kSegmentHeaderSize + lo * rb, block.size(), block.data()));
      if (crc32c::Unmask(s.crcs[b]) != crc32c::Value(block.data(), block.size())) {
        return Status::Corruption(s.path + ": block " + std::to_string(b) +
                                  " checksum mismatch (records of ids " +
                                  Hex(s.first_id + lo) + ".." + Hex(s.first_id + hi - 1) + ")");
      }
      for (uint32_t j = start[b]; j < start[b + 1]; ++j) {
        const uint32_t i = order[j];
        const uint8_t* src = block.data() + (ids[i] - s.first_id - lo) * rb;
        float* dst = out->values.data() + i * stride;
        if (same) {
          std::memcpy(dst, src, rb);
        } else {
          for (size_t f = 0; f < nf; ++f) decoded[f] = DecodeLE<float>(src + 4 * f);
          WidenRecord(decoded, s.degree, dst, degree);
        }
        (*found)[i] = true;
      }
    }
  }
  // Ids without a record read as zeros.
  for (size_t i = 0; i < ids.size(); ++i) {
    if (seg_of[i] < 0) std::fill_n(out->values.data() + i * stride, stride, 0.f);
  }
  return Status::OK();
}

GaussianColumn::Totals GaussianColumn::totals() const {
  std::lock_guard<std::mutex> lk(mu_);
  Totals t;
  for (const auto& [first, s] : segments_) {
    ++t.segments;
    t.records += s->count;
    t.bytes += s->file->size();
  }
  return t;
}

std::vector<std::string> GaussianColumn::Verify() const {
  std::vector<std::string> problems;
  std::vector<std::shared_ptr<const Segment>> segs;
  {
    std::lock_guard<std::mutex> lk(mu_);
    problems = problems_;
    for (const auto& [first, s] : segments_) segs.push_back(s);
  }
  std::vector<uint8_t> block;
  for (const auto& s : segs) {
    const size_t rb = s->record_bytes();
    for (uint64_t b = 0; b < s->crcs.size(); ++b) {
      const uint64_t lo = b * kBlockRecords, hi = std::min<uint64_t>(s->count, lo + kBlockRecords);
      block.resize((hi - lo) * rb);
      Status st = s->file->Read(kSegmentHeaderSize + lo * rb, block.size(), block.data());
      if (!st.ok()) {
        problems.push_back(s->path + ": " + st.message());
        break;
      }
      if (crc32c::Unmask(s->crcs[b]) != crc32c::Value(block.data(), block.size())) {
        problems.push_back(s->path + ": block " + std::to_string(b) + " checksum mismatch");
      }
    }
  }
  return problems;
}

}  // namespace hvdb
