#include "protocol/wire.h"

#include "codec/codec.h"

#include <cmath>
#include <cstring>

#include <draco/compression/decode.h>
#include <draco/compression/encode.h>
#include <draco/point_cloud/point_cloud_builder.h>

#include "storage/coding.h"

namespace hvdb::wire {

void AppendFrame(const google::protobuf::MessageLite& msg, std::string* out) {
  size_t len = msg.ByteSizeLong();
  size_t at = out->size();
  out->resize(at + kFrameHeaderSize + len);
  auto* p = reinterpret_cast<uint8_t*>(out->data() + at);
  EncodeLE(p, static_cast<uint32_t>(len));
  msg.SerializeWithCachedSizesToArray(p + kFrameHeaderSize);
}

std::string Frame(const google::protobuf::MessageLite& msg) {
  std::string s;
  AppendFrame(msg, &s);
  return s;
}

std::string FrameHead(const google::protobuf::MessageLite& msg, uint32_t attachment_len) {
  const size_t len = msg.ByteSizeLong();
  std::string s(kFrameHeaderSize + kAttachmentHeaderSize + len, '\0');
  auto* p = reinterpret_cast<uint8_t*>(s.data());
  EncodeLE(p, static_cast<uint32_t>(len) | kAttachmentFlag);
  EncodeLE(p + kFrameHeaderSize, attachment_len);
  msg.SerializeWithCachedSizesToArray(p + kFrameHeaderSize + kAttachmentHeaderSize);
  return s;
}

bool ParseFrameHeader(const uint8_t header[4], uint32_t max_frame, uint32_t* len,
                      bool* has_attachment) {
  const uint32_t w = DecodeLE<uint32_t>(header);
  *len = w & ~kAttachmentFlag;
  if (has_attachment) *has_attachment = (w & kAttachmentFlag) != 0;
  return *len <= max_frame;
}

FrameReader::Result FrameReader::Next(std::string* payload, std::string* error,
                                      std::string* attachment) {
  if (buf_.size() - pos_ < kFrameHeaderSize) return Result::kNeedMore;
  uint32_t len;
  bool has_att = false;
  const auto* at = reinterpret_cast<const uint8_t*>(buf_.data() + pos_);
  if (!ParseFrameHeader(at, max_frame_, &len, &has_att)) {
    *error = "frame of " + std::to_string(len) + " bytes exceeds the limit of " +
             std::to_string(max_frame_);
    return Result::kBad;
  }
  size_t head = kFrameHeaderSize;
  uint32_t att = 0;
  if (has_att) {
    if (attachment == nullptr) {
      *error = "a frame with an attachment where none may come";
      return Result::kBad;
    }
    if (buf_.size() - pos_ < kFrameHeaderSize + kAttachmentHeaderSize) return Result::kNeedMore;
    att = DecodeLE<uint32_t>(at + kFrameHeaderSize);
    if (att > max_frame_) {
      *error = "attachment of " + std::to_string(att) + " bytes exceeds the limit of " +
               std::to_string(max_frame_);
      return Result::kBad;
    }
    head += kAttachmentHeaderSize;
  }
  if (buf_.size() - pos_ - head < static_cast<size_t>(len) + att) return Result::kNeedMore;
  payload->assign(buf_, pos_ + head, len);
  if (attachment) attachment->assign(buf_, pos_ + head + len, att);
  pos_ += head + len + att;
  if (pos_ > (1u << 16) && pos_ * 2 > buf_.size()) {
    buf_.erase(0, pos_);
    pos_ = 0;
  }
  return Result::kFrame;
}

// ---------------------------------------------------------------------------------------------

namespace {

template <typename T>
void PutColumn(std::string* col, size_t n, const Point* pts, T (*get)(const Point&)) {
  col->resize(n * sizeof(T));
  auto* dst = reinterpret_cast<uint8_t*>(col->data());
  for (size_t i = 0; i < n; ++i) EncodeLE(dst + i * sizeof(T), get(pts[i]));
}

}  // namespace

void EncodeColumns(std::span<const Point> pts, PointColumns* out) {
  const size_t n = pts.size();
  out->set_count(static_cast<uint32_t>(n));
  std::string* id = out->mutable_id();
  id->resize(n * 8);
  std::string* pos = out->mutable_position();
  pos->resize(n * 12);
  std::string* frame = out->mutable_frame();
  frame->resize(n * 4);
  std::string* color = out->mutable_color();
  color->resize(n * 3);
  std::string* cov = out->mutable_covariance();
  cov->resize(n * 24);
  std::string* normal = out->mutable_normal();
  normal->resize(n * 4);
  std::string* label = out->mutable_label();
  label->resize(n * 4);
  std::string* camera = out->mutable_camera();
  camera->resize(n * 2);
  std::string* flags = out->mutable_flags();
  flags->resize(n);
  auto u8 = [](std::string* s) { return reinterpret_cast<uint8_t*>(s->data()); };
  for (size_t i = 0; i < n; ++i) {
    const Point& p = pts[i];
    EncodeLE(u8(id) + 8 * i, p.id);
    EncodeLE(u8(pos) + 12 * i, p.x);
    EncodeLE(u8(pos) + 12 * i + 4, p.y);
    EncodeLE(u8(pos) + 12 * i + 8, p.z);
    EncodeLE(u8(frame) + 4 * i, p.frame);
    u8(color)[3 * i] = p.r;
    u8(color)[3 * i + 1] = p.g;
    u8(color)[3 * i + 2] = p.b;
    for (int k = 0; k < 6; ++k) EncodeLE(u8(cov) + 24 * i + 4 * k, p.cov[k]);
    EncodeLE(u8(normal) + 4 * i, p.normal_oct[0]);
    EncodeLE(u8(normal) + 4 * i + 2, p.normal_oct[1]);
    EncodeLE(u8(label) + 4 * i, p.label);
    EncodeLE(u8(camera) + 2 * i, p.camera);
    u8(flags)[i] = p.flags;
  }
}

void EncodeGaussians(const GaussianColumns& cols, size_t first, size_t n, GaussianRecords* out) {
  out->set_count(static_cast<uint32_t>(n));
  out->set_sh_degree(static_cast<uint32_t>(cols.sh_degree));
  out->set_antialiased(cols.antialiased);
  const size_t stride = cols.stride();
  std::string* v = out->mutable_values();
  v->resize(4 * stride * n);
  auto* dst = reinterpret_cast<uint8_t*>(v->data());
  const float* src = cols.values.data() + first * stride;
  for (size_t k = 0; k < stride * n; ++k) EncodeLE<float>(dst + 4 * k, src[k]);
}

Status DecodeGaussians(const GaussianRecords& in, GaussianColumns* out) {
  if (in.sh_degree() > static_cast<uint32_t>(kMaxGaussianShDegree)) {
    return Status::InvalidArgument("Gaussian records: SH degree " +
                                   std::to_string(in.sh_degree()) + " is not 0..3");
  }
  const int degree = static_cast<int>(in.sh_degree());
  if (!out->values.empty() && degree != out->sh_degree) {
    return Status::InvalidArgument("Gaussian records: SH degree " + std::to_string(degree) +
                                   " after chunks of degree " + std::to_string(out->sh_degree));
  }
  const size_t stride = GaussianRecordFloats(degree);
  if (in.values().size() != 4 * stride * in.count()) {
    return Status::InvalidArgument("Gaussian records: " + std::to_string(in.values().size()) +
                                   " bytes for " + std::to_string(in.count()) +
                                   " records of degree " + std::to_string(degree) + ", expected " +
                                   std::to_string(4 * stride * in.count()));
  }
  out->sh_degree = degree;
  out->antialiased = out->antialiased || in.antialiased();
  const size_t before = out->values.size();
  out->values.resize(before + stride * in.count());
  const auto* src = reinterpret_cast<const uint8_t*>(in.values().data());
  for (size_t k = 0; k < stride * in.count(); ++k) {
    out->values[before + k] = DecodeLE<float>(src + 4 * k);
  }
  return Status::OK();
}

Status DecodeColumns(const PointColumns& in, std::vector<Point>* out) {
  const size_t n = in.count();
  auto check = [&](const std::string& col, size_t width, const char* name) -> Status {
    if (col.size() != n * width) {
      return Status::InvalidArgument(std::string("point columns: '") + name + "' holds " +
                                     std::to_string(col.size()) + " bytes, expected " +
                                     std::to_string(n * width) + " for " + std::to_string(n) +
                                     " points");
    }
    return Status::OK();
  };
  HVDB_RETURN_IF_ERROR(check(in.id(), 8, "id"));
  HVDB_RETURN_IF_ERROR(check(in.position(), 12, "position"));
  HVDB_RETURN_IF_ERROR(check(in.frame(), 4, "frame"));
  HVDB_RETURN_IF_ERROR(check(in.color(), 3, "color"));
  HVDB_RETURN_IF_ERROR(check(in.covariance(), 24, "covariance"));
  HVDB_RETURN_IF_ERROR(check(in.normal(), 4, "normal"));
  HVDB_RETURN_IF_ERROR(check(in.label(), 4, "label"));
  HVDB_RETURN_IF_ERROR(check(in.camera(), 2, "camera"));
  HVDB_RETURN_IF_ERROR(check(in.flags(), 1, "flags"));
  auto u8 = [](const std::string& s) { return reinterpret_cast<const uint8_t*>(s.data()); };
  size_t base = out->size();
  out->resize(base + n);
  for (size_t i = 0; i < n; ++i) {
    Point& p = (*out)[base + i];
    p.id = DecodeLE<uint64_t>(u8(in.id()) + 8 * i);
    p.x = DecodeLE<float>(u8(in.position()) + 12 * i);
    p.y = DecodeLE<float>(u8(in.position()) + 12 * i + 4);
    p.z = DecodeLE<float>(u8(in.position()) + 12 * i + 8);
    p.frame = DecodeLE<uint32_t>(u8(in.frame()) + 4 * i);
    p.r = u8(in.color())[3 * i];
    p.g = u8(in.color())[3 * i + 1];
    p.b = u8(in.color())[3 * i + 2];
    for (int k = 0; k < 6; ++k) p.cov[k] = DecodeLE<float>(u8(in.covariance()) + 24 * i + 4 * k);
    p.normal_oct[0] = DecodeLE<int16_t>(u8(in.normal()) + 4 * i);
    p.normal_oct[1] = DecodeLE<int16_t>(u8(in.normal()) + 4 * i + 2);
    p.label = DecodeLE<uint32_t>(u8(in.label()) + 4 * i);
    p.camera = DecodeLE<uint16_t>(u8(in.camera()) + 2 * i);
    p.flags = u8(in.flags())[i];
  }
  return Status::OK();
}

Status EncodeDraco(std::span<const Point> pts, int position_bits, std::string* out) {
  draco::PointCloudBuilder b;
  b.Start(static_cast<draco::PointIndex::ValueType>(pts.size()));
  const int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  const int col = b.AddAttribute(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT8);
  const int ids = b.AddAttribute(draco::GeometryAttribute::GENERIC, 2, draco::DT_UINT32);
  const int frm = b.AddAttribute(draco::GeometryAttribute::GENERIC, 1, draco::DT_UINT32);
  for (size_t i = 0; i < pts.size(); ++i) {
    const Point& p = pts[i];
    draco::PointIndex pi(static_cast<draco::PointIndex::ValueType>(i));
    const float xyz[3] = {p.x, p.y, p.z};
    const uint8_t rgb[3] = {p.r, p.g, p.b};
    const uint32_t id[2] = {static_cast<uint32_t>(p.id), static_cast<uint32_t>(p.id >> 32)};
    b.SetAttributeValueForPoint(pos, pi, xyz);
    b.SetAttributeValueForPoint(col, pi, rgb);
    b.SetAttributeValueForPoint(ids, pi, id);
    b.SetAttributeValueForPoint(frm, pi, &p.frame);
  }
  std::unique_ptr<draco::PointCloud> pc = b.Finalize(/*deduplicate_points=*/false);
  if (!pc) return Status::Internal("draco: could not build the point cloud");
  draco::Encoder enc;
  enc.SetAttributeQuantization(draco::GeometryAttribute::POSITION, position_bits);
  enc.SetSpeedOptions(5, 5);
  draco::EncoderBuffer buf;
  draco::Status st = enc.EncodePointCloudToBuffer(*pc, &buf);
  if (!st.ok()) return Status::Internal(std::string("draco encode: ") + st.error_msg());
  out->assign(buf.data(), buf.size());
  return Status::OK();
}

Status DecodeDraco(const std::string& data, std::vector<Point>* out) {
  draco::DecoderBuffer buf;
  buf.Init(data.data(), data.size());
  draco::Decoder dec;
  auto res = dec.DecodePointCloudFromBuffer(&buf);
  if (!res.ok()) {
    return Status::InvalidArgument(std::string("draco decode: ") + res.status().error_msg());
  }
  std::unique_ptr<draco::PointCloud> pc = std::move(res).value();
  const draco::PointAttribute* pos = pc->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  const draco::PointAttribute* col = pc->GetNamedAttribute(draco::GeometryAttribute::COLOR);
  const draco::PointAttribute* ids = pc->GetNamedAttribute(draco::GeometryAttribute::GENERIC, 0);
  const draco::PointAttribute* frm = pc->GetNamedAttribute(draco::GeometryAttribute::GENERIC, 1);
  if (!pos || !col || !ids || !frm || pos->num_components() != 3 || col->num_components() != 3 ||
      ids->num_components() != 2 || frm->num_components() != 1) {
    return Status::InvalidArgument("draco decode: not an hvdb point batch");
  }
  size_t base = out->size();
  out->resize(base + pc->num_points());
  for (draco::PointIndex i(0); i < pc->num_points(); ++i) {
    Point& p = (*out)[base + i.value()];
    float xyz[3];
    uint8_t rgb[3];
    uint32_t id[2];
    pos->GetMappedValue(i, xyz);
    col->GetMappedValue(i, rgb);
    ids->GetMappedValue(i, id);
    frm->GetMappedValue(i, &p.frame);
    p.x = xyz[0];
    p.y = xyz[1];
    p.z = xyz[2];
    p.r = rgb[0];
    p.g = rgb[1];
    p.b = rgb[2];
    p.id = uint64_t{id[0]} | (uint64_t{id[1]} << 32);
  }
  return Status::OK();
}

// ---------------------------------------------------------------------------------------------

namespace {

Status Invalid(const std::string& parameter, const std::string& why) {
  return Status::InvalidArgument(parameter + ": " + why);
}

Result<std::array<double, 4>> Four(const google::protobuf::RepeatedField<double>& v,
                                   const std::string& name) {
  if (v.size() != 4) {
    return Invalid(name, "needs exactly 4 values, got " + std::to_string(v.size()));
  }
  // Only the shape is checked here: the values (NaN, empty ranges, a zero normal) are the
  // engine's to judge (storage/hyperslice.h), so that embedded and remote callers get one answer.
  std::array<double, 4> a{};
  for (int i = 0; i < 4; ++i) a[static_cast<size_t>(i)] = v[i];
  return a;
}

Result<hvdb::Window> WindowFromWire(const wire::Window& w, const std::string& name) {
  hvdb::Window out;
  HVDB_ASSIGN_OR_RETURN(out.lo, Four(w.lo(), name + ".lo"));
  HVDB_ASSIGN_OR_RETURN(out.hi, Four(w.hi(), name + ".hi"));
  return out;
}

void WindowToWire(const hvdb::Window& w, wire::Window* out) {
  for (double v : w.lo) out->add_lo(v);
  for (double v : w.hi) out->add_hi(v);
}

}  // namespace

void ToWire(const hvdb::Region& r, wire::Region* out) {
  if (const auto* w = std::get_if<hvdb::Window>(&r)) {
    WindowToWire(*w, out->mutable_window());
    return;
  }
  const auto& s = std::get<hvdb::Slice>(r);
  wire::Slice* o = out->mutable_slice();
  for (double v : s.normal) o->add_normal(v);
  o->set_offset(s.offset);
  o->set_thickness(s.thickness);
  if (s.clip) WindowToWire(*s.clip, o->mutable_clip());
  o->set_clip_frames(s.on_too_many_frames == hvdb::Slice::FrameBound::kClip);
  o->set_max_frames(s.max_frames);
}

Result<hvdb::Region> FromWire(const wire::Region& r) {
  switch (r.kind_case()) {
    case wire::Region::kWindow: {
      HVDB_ASSIGN_OR_RETURN(hvdb::Window w, WindowFromWire(r.window(), "window"));
      return hvdb::Region(w);
    }
    case wire::Region::kSlice: {
      const wire::Slice& s = r.slice();
      hvdb::Slice out;
      HVDB_ASSIGN_OR_RETURN(out.normal, Four(s.normal(), "slice.normal"));
      out.offset = s.offset();
      out.thickness = s.thickness();
      if (s.has_clip()) {
        HVDB_ASSIGN_OR_RETURN(hvdb::Window clip, WindowFromWire(s.clip(), "slice.clip"));
        out.clip = clip;
      }
      out.on_too_many_frames =
          s.clip_frames() ? hvdb::Slice::FrameBound::kClip : hvdb::Slice::FrameBound::kError;
      out.max_frames = s.max_frames();
      return hvdb::Region(out);
    }
    default:
      return Invalid("region", "must be a window or a slice");
  }
}

void ToWire(const CameraInfo& c, wire::Camera* out) {
  out->set_id(c.id);
  out->set_name(c.name);
  out->set_width(c.width);
  out->set_height(c.height);
  for (double v : {c.fx, c.fy, c.cx, c.cy}) out->add_intrinsics(v);
  for (double v : c.distortion) out->add_distortion(v);
  for (double v : c.world_from_camera) out->add_world_from_camera(v);
}

Result<CameraInfo> FromWire(const wire::Camera& c) {
  CameraInfo out;
  if (c.id() > 65535) return Invalid("camera.id", "must fit 16 bits");
  if (c.intrinsics_size() != 4) return Invalid("camera.intrinsics", "needs fx fy cx cy");
  if (c.distortion_size() != 0 && c.distortion_size() != 5) {
    return Invalid("camera.distortion", "needs 5 values (k1 k2 p1 p2 k3) or none");
  }
  if (c.world_from_camera_size() != 16) return Invalid("camera.world_from_camera", "needs 16 values");
  out.id = static_cast<uint16_t>(c.id());
  out.name = c.name();
  out.width = c.width();
  out.height = c.height();
  out.fx = c.intrinsics(0);
  out.fy = c.intrinsics(1);
  out.cx = c.intrinsics(2);
  out.cy = c.intrinsics(3);
  for (int i = 0; i < c.distortion_size(); ++i) out.distortion[static_cast<size_t>(i)] = c.distortion(i);
  for (int i = 0; i < 16; ++i) out.world_from_camera[static_cast<size_t>(i)] = c.world_from_camera(i);
  return out;
}

void ToWire(const hvdb::DatasetInfo& info, wire::DatasetInfo* out) {
  out->set_name(info.name);
  out->set_fps(info.fps);
  out->set_space_time_scale(info.space_time_scale);
  out->set_frame_count(info.frame_count);
  for (float v : info.bounds_min) out->add_bounds_min(v);
  for (float v : info.bounds_max) out->add_bounds_max(v);
  out->set_point_count(info.point_count);
  out->set_last_lsn(info.last_lsn);
  out->set_gaussians(info.gaussians);
  for (const CameraInfo& c : info.cameras) ToWire(c, out->add_cameras());
}

hvdb::DatasetInfo FromWire(const wire::DatasetInfo& in) {
  hvdb::DatasetInfo info;
  info.name = in.name();
  info.fps = in.fps();
  info.space_time_scale = in.space_time_scale();
  info.frame_count = in.frame_count();
  for (int i = 0; i < 3 && i < in.bounds_min_size(); ++i) info.bounds_min[static_cast<size_t>(i)] = in.bounds_min(i);
  for (int i = 0; i < 3 && i < in.bounds_max_size(); ++i) info.bounds_max[static_cast<size_t>(i)] = in.bounds_max(i);
  info.point_count = in.point_count();
  info.last_lsn = in.last_lsn();
  info.gaussians = in.gaussians();
  for (const auto& c : in.cameras()) {
    auto cam = FromWire(c);
    if (cam.ok()) info.cameras.push_back(*cam);
  }
  return info;
}

void ToWire(const hvdb::Selection& s, wire::Selection* out) {
  if (s.region) ToWire(*s.region, out->mutable_region());
  out->set_label_mask(s.label_mask);
  for (auto [f, id] : s.ids) {
    out->add_frames(f);
    out->add_ids(id);
  }
}

Result<hvdb::Selection> FromWire(const wire::Selection& s) {
  hvdb::Selection out;
  if (s.has_region()) {
    HVDB_ASSIGN_OR_RETURN(hvdb::Region r, FromWire(s.region()));
    out.region = r;
  }
  out.label_mask = s.label_mask();
  if (s.frames_size() != s.ids_size()) {
    return Invalid("selection.ids", "needs one frame per id");
  }
  for (int i = 0; i < s.ids_size(); ++i) out.ids.emplace_back(s.frames(i), s.ids(i));
  return out;
}

Result<Transaction> FromWire(const wire::Edit& e) {
  Transaction t;
  for (int i = 0; i < e.ops_size(); ++i) {
    const wire::EditOp& op = e.ops(i);
    const std::string where = "ops[" + std::to_string(i) + "]";
    switch (op.op_case()) {
      case wire::EditOp::kInsert: {
        std::vector<Point> pts;
        Status st = DecodeColumns(op.insert(), &pts);
        if (!st.ok()) return Invalid(where + ".insert", st.message());
        t.Insert(std::move(pts));
        break;
      }
      case wire::EditOp::kDeletePoint: {
        const auto& d = op.delete_point();
        if (d.position_size() != 3) return Invalid(where + ".delete_point.position", "needs 3 values");
        t.Delete(d.id(), d.frame(), {d.position(0), d.position(1), d.position(2)});
        break;
      }
      case wire::EditOp::kDeleteSelection: {
        HVDB_ASSIGN_OR_RETURN(hvdb::Selection s, FromWire(op.delete_selection()));
        t.DeleteSelection(std::move(s));
        break;
      }
      case wire::EditOp::kTransform: {
        const auto& tr = op.transform();
        HVDB_ASSIGN_OR_RETURN(hvdb::Selection s, FromWire(tr.selection()));
        if (tr.matrix_size() != 16) return Invalid(where + ".transform.matrix", "needs 16 values");
        if (tr.offset_size() != 4) return Invalid(where + ".transform.offset", "needs 4 values");
        Affine4 a;
        for (int k = 0; k < 16; ++k) a.a[static_cast<size_t>(k)] = tr.matrix(k);
        for (int k = 0; k < 4; ++k) a.c[static_cast<size_t>(k)] = tr.offset(k);
        t.Transform(std::move(s), a);
        break;
      }
      case wire::EditOp::kSetLabel: {
        HVDB_ASSIGN_OR_RETURN(hvdb::Selection s, FromWire(op.set_label().selection()));
        t.SetLabel(std::move(s), op.set_label().bits(), op.set_label().set());
        break;
      }
      default:
        return Invalid(where, "empty or unknown operation");
    }
  }
  return t;
}

void ToWire(const Transaction& t, wire::Edit* out) {
  for (const Transaction::Op& op : t.ops()) {
    wire::EditOp* o = out->add_ops();
    if (const auto* ins = std::get_if<Transaction::InsertOp>(&op)) {
      EncodeColumns(ins->points, o->mutable_insert());
    } else if (const auto* del = std::get_if<Transaction::DeleteOp>(&op)) {
      auto* d = o->mutable_delete_point();
      d->set_id(del->id);
      d->set_frame(del->frame);
      for (float v : del->pos) d->add_position(v);
    } else if (const auto* ds = std::get_if<Transaction::DeleteSelOp>(&op)) {
      ToWire(ds->sel, o->mutable_delete_selection());
    } else if (const auto* tr = std::get_if<Transaction::TransformOp>(&op)) {
      auto* x = o->mutable_transform();
      ToWire(tr->sel, x->mutable_selection());
      for (double v : tr->map.a) x->add_matrix(v);
      for (double v : tr->map.c) x->add_offset(v);
    } else if (const auto* lb = std::get_if<Transaction::LabelOp>(&op)) {
      auto* l = o->mutable_set_label();
      ToWire(lb->sel, l->mutable_selection());
      l->set_bits(lb->bits);
      l->set_set(lb->set);
    }
  }
}

ErrorCode ToWire(StatusCode code) {
  switch (code) {
    case StatusCode::kOk: return ERROR_UNSPECIFIED;
    case StatusCode::kNotFound: return NOT_FOUND;
    case StatusCode::kInvalidArgument: return INVALID_PARAMETER;
    case StatusCode::kCorruption: return CORRUPT_DATA;
    case StatusCode::kIOError: return IO_ERROR;
    case StatusCode::kLimitExceeded: return LIMIT_EXCEEDED;
    case StatusCode::kAlreadyExists: return ALREADY_EXISTS;
    case StatusCode::kCancelled: return CANCELLED;
    case StatusCode::kInternal: return INTERNAL;
    case StatusCode::kPermissionDenied: return PERMISSION_DENIED;
    case StatusCode::kOverloaded: return OVERLOADED;
    case StatusCode::kUnsupported: return UNSUPPORTED;
    case StatusCode::kNotLeader: return NOT_LEADER;
  }
  return INTERNAL;
}

StatusCode FromWire(ErrorCode code) {
  switch (code) {
    case UNKNOWN_DATASET:
    case NOT_FOUND: return StatusCode::kNotFound;
    case INVALID_PARAMETER:
    case MALFORMED: return StatusCode::kInvalidArgument;
    case LIMIT_EXCEEDED: return StatusCode::kLimitExceeded;
    case PERMISSION_DENIED: return StatusCode::kPermissionDenied;
    case CORRUPT_DATA: return StatusCode::kCorruption;
    case OVERLOADED: return StatusCode::kOverloaded;
    case CANCELLED: return StatusCode::kCancelled;
    case ALREADY_EXISTS: return StatusCode::kAlreadyExists;
    case UNSUPPORTED: return StatusCode::kUnsupported;
    case IO_ERROR: return StatusCode::kIOError;
    case NOT_LEADER: return StatusCode::kNotLeader;
    default: return StatusCode::kInternal;
  }
}

void ToWire(const Status& s, wire::Error* out) {
  out->set_code(ToWire(s.code()));
  out->set_message(s.message());
  if (s.code() == StatusCode::kInvalidArgument) {
    auto colon = s.message().find(':');
    if (colon != std::string::npos && colon < 64) out->set_parameter(s.message().substr(0, colon));
  }
}

Status FromWire(const wire::Error& e) {
  StatusCode code = FromWire(e.code());
  if (code == StatusCode::kOk) code = StatusCode::kInternal;
  return {code, e.message()};
}

namespace {

Status Hvdb7Options(const CodecParams& params, codec::EncodeOptions* o) {
  o->attributes = codec::kAllAttributes;
  if (!params.attributes().empty()) {
    Status st = codec::ParseAttributes(params.attributes(), &o->attributes);
    if (!st.ok()) {
      return Status::InvalidArgument("query.codec.attributes: " + st.message() +
                                     "; list them comma-separated, or leave it empty for all");
    }
  }
  auto pick = [](uint32_t v, int dflt, uint32_t lo, uint32_t hi, const char* field,
                 int* dst) -> Status {
    if (v == 0) {
      *dst = dflt;
      return Status::OK();
    }
    if (v < lo || v > hi) {
      return Status::InvalidArgument("query.codec." + std::string(field) + ": " +
                                     std::to_string(v) + " is out of range " + std::to_string(lo) +
                                     ".." + std::to_string(hi));
    }
    *dst = static_cast<int>(v);
    return Status::OK();
  };
  HVDB_RETURN_IF_ERROR(pick(params.position_bits(), 16, 1, 30, "position_bits", &o->qp));
  HVDB_RETURN_IF_ERROR(pick(params.color_bits(), 8, 1, 8, "color_bits", &o->qc));
  HVDB_RETURN_IF_ERROR(pick(params.normal_bits(), 12, 1, 16, "normal_bits", &o->qn));
  HVDB_RETURN_IF_ERROR(pick(params.covariance_bits(), 6, 1, 20, "covariance_bits", &o->qcov));
  return Status::OK();
}

}  // namespace

Status CheckHvdb7Params(const CodecParams& params) {
  codec::EncodeOptions o;
  return Hvdb7Options(params, &o);
}

Status EncodeHvdb7(std::span<const Point> pts, const CodecParams& params, std::string* out) {
  codec::EncodeOptions o;
  HVDB_RETURN_IF_ERROR(Hvdb7Options(params, &o));
  o.progressive = true;
  o.chunk = 4096;
  o.effort = 0;  // coded on the fly: the faster pairing
  return codec::Encode(pts, o, out);
}

Status DecodeHvdb7(const std::string& data, std::vector<Point>* out) {
  std::vector<Point> pts;
  codec::DecodeOptions o;
  o.max_points = kMaxBatchPoints;
  HVDB_RETURN_IF_ERROR(codec::Decode(data, &pts, o));
  out->insert(out->end(), pts.begin(), pts.end());
  return Status::OK();
}

}  // namespace hvdb::wire
