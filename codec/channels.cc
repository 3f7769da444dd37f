// Points as integer channels (quantisation and the colour/covariance transforms), and the
// stream header. docs/CODEC.md, "Channels" and "Header".
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include "codec/internal.h"
#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb::codec {
namespace {

// Floats as integers that order like the floats: exact (lossless) channels.
int64_t OrderedInt(float f) {
  int32_t i = std::bit_cast<int32_t>(f);
  return i >= 0 ? i : static_cast<int32_t>(static_cast<uint32_t>(i) ^ 0x7FFFFFFFu);
}
float FromOrderedInt(int64_t v) {
  int32_t i = static_cast<int32_t>(v);
  if (i < 0) i = static_cast<int32_t>(static_cast<uint32_t>(i) ^ 0x7FFFFFFFu);
  return std::bit_cast<float>(i);
}

// Rounding right shift of a signed value (s >= 0).
int64_t QuantShift(int64_t v, int s) { return s == 0 ? v : (v + (int64_t{1} << (s - 1))) >> s; }

int LumaShift(int qc) { return 8 - qc; }
int ChromaShift(int qc) { return qc >= 8 ? 0 : 9 - qc; }

constexpr double kMinCholesky = 1e-12;

}  // namespace

void Columns::Resize(size_t count, uint32_t attributes) {
  n = count;
  for (int c = 0; c < kChannels; ++c) {
    if ((attributes >> GroupOf(c)) & 1u) ch[c].resize(count);
  }
}

void Quantizer::Fit(std::span<const Point> pts) {
  double lo[3] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                  std::numeric_limits<double>::infinity()};
  double hi[3] = {-lo[0], -lo[0], -lo[0]};
  for (const Point& p : pts) {
    const float xyz[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], double{xyz[a]});
      hi[a] = std::max(hi[a], double{xyz[a]});
    }
  }
  double extent = 0;
  for (int a = 0; a < 3; ++a) {
    origin[a] = pts.empty() ? 0.0 : lo[a];
    if (!pts.empty()) extent = std::max(extent, hi[a] - lo[a]);
  }
  step = (qp > 0 && extent > 0) ? extent / static_cast<double>((uint64_t{1} << qp) - 1) : 1.0;
}

void Quantizer::ToChannels(const Point& p, int64_t* c) const {
  const float xyz[3] = {p.x, p.y, p.z};
  for (int a = 0; a < 3; ++a) {
    if (qp == 0) {
      c[a] = OrderedInt(xyz[a]);
    } else {
      double v = std::llround((xyz[a] - origin[a]) / step);
      c[a] = static_cast<int64_t>(std::clamp(v, 0.0, static_cast<double>((uint64_t{1} << qp) - 1)));
    }
  }
  if (Has(1)) {  // YCoCg-R (lossless, integer; 7.3.2 asks for a luma/chroma space)
    int co = int{p.r} - int{p.b};
    int t = int{p.b} + (co >> 1);
    int cg = int{p.g} - t;
    int y = t + (cg >> 1);
    c[3] = QuantShift(y, LumaShift(qc));
    c[4] = QuantShift(co, ChromaShift(qc));
    c[5] = QuantShift(cg, ChromaShift(qc));
  }
  if (Has(2)) {
    int s = 16 - qn;
    c[6] = QuantShift(p.normal_oct[0], s);
    c[7] = QuantShift(p.normal_oct[1], s);
  }
  if (Has(3)) {
    if (qcov == 0) {
      for (int i = 0; i < 6; ++i) c[8 + i] = OrderedInt(p.cov[i]);
    } else {
      // log-Cholesky: V = L L^T with log2 of the diagonal and the off-diagonals relative to
      // their column's diagonal, each in 2^-qcov steps. Any decoded value gives a valid
      // (positive semi-definite) covariance.
      double xx = p.cov[0], xy = p.cov[1], xz = p.cov[2], yy = p.cov[3], yz = p.cov[4],
             zz = p.cov[5];
      double l00 = std::sqrt(std::max(xx, kMinCholesky * kMinCholesky));
      double l10 = xy / l00, l20 = xz / l00;
      double l11 = std::sqrt(std::max(yy - l10 * l10, kMinCholesky * kMinCholesky));
      double l21 = (yz - l20 * l10) / l11;
      double l22 = std::sqrt(std::max(zz - l20 * l20 - l21 * l21, kMinCholesky * kMinCholesky));
      double sc = std::ldexp(1.0, qcov);
      auto q = [&](double v) {
        return static_cast<int64_t>(std::llround(std::clamp(v * sc, -1e15, 1e15)));
      };
      c[8] = q(std::log2(l00));
      c[9] = q(std::log2(l11));
      c[10] = q(std::log2(l22));
      c[11] = q(l10 / l00);
      c[12] = q(l20 / l00);
      c[13] = q(l21 / l11);
    }
  }
  if (Has(4)) c[14] = static_cast<int64_t>(p.id);
  if (Has(5)) c[15] = p.frame;
  if (Has(6)) c[16] = p.label;
  if (Has(7)) c[17] = p.camera;
  if (Has(8)) c[18] = p.flags;
}

void Quantizer::ToPoint(const int64_t* c, Point* p) const {
  *p = Point{};
  float* xyz[3] = {&p->x, &p->y, &p->z};
  for (int a = 0; a < 3; ++a) {
    *xyz[a] = qp == 0 ? FromOrderedInt(c[a])
                      : static_cast<float>(origin[a] + static_cast<double>(c[a]) * step);
  }
  uint8_t flags = Has(8) ? static_cast<uint8_t>(c[18]) : 0;
  // Decoded values of a valid stream are small; clamping first keeps any stream's arithmetic
  // defined (a corrupt one that passed its checksums decodes to wrong values, never to UB).
  auto small = [](int64_t v) { return std::clamp<int64_t>(v, -(int64_t{1} << 20), int64_t{1} << 20); };
  if (Has(1)) {
    int y = static_cast<int>(small(c[3]) * (int64_t{1} << LumaShift(qc)));
    int co = static_cast<int>(small(c[4]) * (int64_t{1} << ChromaShift(qc)));
    int cg = static_cast<int>(small(c[5]) * (int64_t{1} << ChromaShift(qc)));
    int t = y - (cg >> 1);
    int g = cg + t;
    int b = t - (co >> 1);
    int r = b + co;
    p->r = static_cast<uint8_t>(std::clamp(r, 0, 255));
    p->g = static_cast<uint8_t>(std::clamp(g, 0, 255));
    p->b = static_cast<uint8_t>(std::clamp(b, 0, 255));
  }
  if (Has(2)) {
    int s = 16 - qn;
    for (int i = 0; i < 2; ++i) {
      int64_t v = small(c[6 + i]) * (int64_t{1} << s);
      p->normal_oct[i] = static_cast<int16_t>(std::clamp<int64_t>(v, -32767, 32767));
    }
  } else {
    flags &= static_cast<uint8_t>(~kFlagHasNormal);
  }
  if (Has(3)) {
    if (qcov == 0) {
      for (int i = 0; i < 6; ++i) p->cov[i] = FromOrderedInt(c[8 + i]);
    } else {
      double sc = std::ldexp(1.0, -qcov);
      auto dq = [&](int64_t v) { return static_cast<double>(v) * sc; };
      double l00 = std::exp2(std::clamp(dq(c[8]), -60.0, 60.0));
      double l11 = std::exp2(std::clamp(dq(c[9]), -60.0, 60.0));
      double l22 = std::exp2(std::clamp(dq(c[10]), -60.0, 60.0));
      double l10 = dq(c[11]) * l00, l20 = dq(c[12]) * l00, l21 = dq(c[13]) * l11;
      auto f = [](double v) {  // a corrupt stream must not overflow the conversion
        return static_cast<float>(std::clamp(v, -3.0e38, 3.0e38));
      };
      p->cov = {f(l00 * l00), f(l10 * l00), f(l20 * l00), f(l10 * l10 + l11 * l11),
                f(l20 * l10 + l21 * l11), f(l20 * l20 + l21 * l21 + l22 * l22)};
    }
  } else {
    flags &= static_cast<uint8_t>(~kFlagHasCovariance);
  }
  if (Has(4)) p->id = static_cast<uint64_t>(c[14]);
  if (Has(5)) p->frame = static_cast<uint32_t>(c[15]);
  if (Has(6)) p->label = static_cast<uint32_t>(c[16]);
  if (Has(7)) p->camera = static_cast<uint16_t>(c[17]);
  p->flags = flags;
}

int AutoLevels(uint64_t n) {
  int l = 0;
  while (LevelSize(n, l) > 512 && l < 40) ++l;
  return l;
}

uint32_t ReferenceCrc(std::span<const Point> pts) {
  uint32_t crc = 0;
  uint8_t rec[kPointRecordSize];
  for (const Point& p : pts) {
    EncodePoint(p, rec);
    crc = crc32c::Extend(crc, rec, sizeof rec);
  }
  return crc;
}

// Header, all little-endian (docs/CODEC.md):
//   magic "HV7C", u8 version, u8 flags, u16 attributes, u64 points, u8 levels, u8 qp, u8 qc,
//   u8 qn, u8 qcov, 3 x u8 reserved (0), u32 chunk, u64 plane mask, f64 origin[3], f64 step,
//   u32 singleton[levels], [temporal: u64 reference points, u32 reference CRC32C],
//   u32 CRC32C of everything before it.
void WriteHeader(const Header& h, std::string* out) {
  Writer w;
  w.PutBytes(kMagic, 4);
  w.Put<uint8_t>((h.flags & kOctree) ? kOctreeVersion : kVersion);
  w.Put<uint8_t>(h.flags);
  w.Put<uint16_t>(static_cast<uint16_t>(h.attributes));
  w.Put<uint64_t>(h.points);
  w.Put<uint8_t>(static_cast<uint8_t>(h.levels));
  w.Put<uint8_t>(static_cast<uint8_t>(h.q.qp));
  w.Put<uint8_t>(static_cast<uint8_t>(h.q.qc));
  w.Put<uint8_t>(static_cast<uint8_t>(h.q.qn));
  w.Put<uint8_t>(static_cast<uint8_t>(h.q.qcov));
  for (int i = 0; i < 3; ++i) w.Put<uint8_t>(0);
  w.Put<uint32_t>(h.chunk);
  w.Put<uint64_t>(h.plane_mask);
  for (int a = 0; a < 3; ++a) w.Put<double>(h.q.origin[a]);
  w.Put<double>(h.q.step);
  for (uint32_t s : h.singleton) w.Put<uint32_t>(s);
  if (h.flags & kTemporal) {
    w.Put<uint64_t>(h.reference_points);
    w.Put<uint32_t>(h.reference_crc);
  }
  w.Put<uint32_t>(crc32c::Value(w.data().data(), w.data().size()));
  out->append(w.data());
}

Status ParseHeader(std::string_view s, const DecodeOptions* opts, Header* h, size_t* used) {
  const auto* p = reinterpret_cast<const uint8_t*>(s.data());
  constexpr size_t kFixed = 4 + 1 + 1 + 2 + 8 + 1 + 4 + 3 + 4 + 8 + 32;
  if (s.size() < 4 || std::memcmp(p, kMagic, 4) != 0) {
    return Status::InvalidArgument("not an hvdb7 point stream (magic \"HV7C\" missing)");
  }
  if (s.size() < kFixed + 4) return Status::Corruption("hvdb7 stream truncated in its header");
  Reader r(p + 4, s.size() - 4);
  uint8_t version = 0, flags = 0, levels = 0, qp = 0, qc = 0, qn = 0, qcov = 0, res[3] = {};
  uint16_t attrs = 0;
  r.Get(&version);
  if (version != kVersion && version != kOctreeVersion) {
    return Status::Unsupported("hvdb7 stream version " + std::to_string(version) +
                               " (this build reads versions 1 and 2)");
  }
  r.Get(&flags);
  if (((flags & kOctree) != 0) != (version == kOctreeVersion)) {
    return Status::Corruption("hvdb7 header: the octree flag does not match the version");
  }
  r.Get(&attrs);
  r.Get(&h->points);
  r.Get(&levels);
  r.Get(&qp);
  r.Get(&qc);
  r.Get(&qn);
  r.Get(&qcov);
  for (auto& b : res) r.Get(&b);
  r.Get(&h->chunk);
  r.Get(&h->plane_mask);
  for (auto& o : h->q.origin) r.Get(&o);
  r.Get(&h->q.step);
  size_t need = kFixed + 4 * size_t{levels} + ((flags & kTemporal) ? 12 : 0) + 4;
  if (s.size() < need) return Status::Corruption("hvdb7 stream truncated in its header");
  uint32_t crc = DecodeLE<uint32_t>(p + need - 4);
  if (crc != crc32c::Value(p, need - 4)) return Status::Corruption("hvdb7 header checksum mismatch");
  if ((flags & ~(kProgressive | kTemporal | kOctree)) != 0 ||
      ((flags & kOctree) && (qp < 1 || qp > 21 || h->plane_mask != 0)) || (attrs & ~kAllAttributes) != 0 ||
      !(attrs & kPosition) || qp > 30 || qc < 1 || qc > 8 || qn < 1 || qn > 16 || qcov > 20 ||
      levels > 40 || h->chunk == 0 || !std::isfinite(h->q.step) || h->q.step <= 0) {
    return Status::Corruption("hvdb7 header holds out-of-range parameters");
  }
  for (double o : h->q.origin) {
    if (!std::isfinite(o)) return Status::Corruption("hvdb7 header holds a non-finite origin");
  }
  uint64_t max_points = opts ? opts->max_points : (1ull << 27);
  if (h->points > max_points) {
    return Status::LimitExceeded("hvdb7 stream holds " + std::to_string(h->points) +
                                 " points, more than the limit of " + std::to_string(max_points));
  }
  if (levels > 0 && LevelSize(h->points, levels) == 0 && h->points == 0) {
    return Status::Corruption("hvdb7 header: levels on an empty point set");
  }
  h->flags = flags;
  h->attributes = attrs;
  h->levels = levels;
  h->q.qp = qp;
  h->q.qc = qc;
  h->q.qn = qn;
  h->q.qcov = qcov;
  h->q.attributes = attrs;
  h->singleton.resize(levels);
  for (int k = 0; k < levels; ++k) {
    r.Get(&h->singleton[k]);
    uint64_t below = LevelSize(h->points, k);
    uint64_t size = LevelSize(h->points, k + 1);
    bool odd = below % 2 == 1;
    // Octree streams pair consecutive points: the unpaired one is the last.
    const bool octree = (flags & kOctree) != 0;
    if (odd ? (octree ? h->singleton[k] != size - 1 : h->singleton[k] >= size)
            : h->singleton[k] != kNoChild) {
      return Status::Corruption("hvdb7 header: bad unpaired-point index at level " +
                                std::to_string(k + 1));
    }
  }
  if (flags & kTemporal) {
    r.Get(&h->reference_points);
    r.Get(&h->reference_crc);
  }
  *used = need;
  return Status::OK();
}

Status ParseAttributes(std::string_view list, uint32_t* mask) {
  static constexpr std::string_view kNames[kGroups] = {"position", "color",  "normal",
                                                       "covariance", "id",  "frame",
                                                       "label",    "camera", "flags"};
  uint32_t m = kPosition;
  while (!list.empty()) {
    size_t comma = list.find(',');
    std::string_view name = list.substr(0, comma);
    list = comma == std::string_view::npos ? std::string_view{} : list.substr(comma + 1);
    if (name == "all") {
      m |= kAllAttributes;
      continue;
    }
    if (name == "colour") name = "color";
    bool found = false;
    for (int g = 0; g < kGroups; ++g) {
      if (name == kNames[g]) {
        m |= 1u << g;
        found = true;
      }
    }
    if (!found) {
      return Status::InvalidArgument("unknown attribute '" + std::string(name) +
                                     "' (position, color, normal, covariance, id, frame, label, "
                                     "camera, flags, all)");
    }
  }
  *mask = m;
  return Status::OK();
}

std::string AttributeNames(uint32_t mask) {
  static constexpr const char* kNames[kGroups] = {"position", "color", "normal",
                                                  "covariance", "id", "frame",
                                                  "label", "camera", "flags"};
  std::string s;
  for (int g = 0; g < kGroups; ++g) {
    if ((mask >> g) & 1u) {
      if (!s.empty()) s += ',';
      s += kNames[g];
    }
  }
  return s;
}

}  // namespace hvdb::codec
