#include "storage/photos.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/dataset_impl.h"
#include "storage/env.h"

namespace hvdb {

namespace {

using photo_io::GetF64;
using photo_io::PhotoDir;
using photo_io::Put;
using photo_io::PutF64;

constexpr char kMagic[8] = {'H', 'V', 'D', 'B', 'P', 'H', 'O', '\0'};
constexpr uint32_t kVersion = 1;           // a photo
constexpr uint32_t kVersionBillboard = 2;  // a photo with its billboard
constexpr size_t kMaxName = 255;
// magic, version, camera id, name length, width, height, 4 intrinsics, 5 distortion, 16 pose,
// image length; then the name, the image and the CRC.
constexpr size_t kFixed = 8 + 4 + 2 + 2 + 4 + 4 + 8 * (4 + 5 + 16) + 8;
constexpr uint64_t kMaxImage = uint64_t{1} << 30;
// Version 2 only, after the image length: scale, 3 plane coefficients, the two maps' lengths.
constexpr size_t kBillboardFixed = 8 * 4 + 8 + 8;



}  // namespace

std::string PhotoFileName(uint32_t frame, uint16_t camera) {
  char name[32];
  std::snprintf(name, sizeof name, "%08u-%05u.photo", frame, static_cast<unsigned>(camera));
  return name;
}

std::string EncodePhoto(const Photo& photo) {
  const CameraInfo& c = photo.camera;
  const PhotoBillboard& b = photo.billboard;
  const bool billboard = b.scale != 0;
  const std::string name = c.name.substr(0, kMaxName);
  std::string out(kMagic, 8);
  Put<uint32_t>(&out, billboard ? kVersionBillboard : kVersion);
  Put<uint16_t>(&out, c.id);
  Put<uint16_t>(&out, static_cast<uint16_t>(name.size()));
  Put<uint32_t>(&out, c.width);
  Put<uint32_t>(&out, c.height);
  for (double v : {c.fx, c.fy, c.cx, c.cy}) PutF64(&out, v);
  for (double v : c.distortion) PutF64(&out, v);
  for (double v : c.world_from_camera) PutF64(&out, v);
  Put<uint64_t>(&out, photo.image.size());
  if (billboard) {
    PutF64(&out, b.scale);
    for (double v : b.plane) PutF64(&out, v);
    Put<uint64_t>(&out, b.displacement.size());
    Put<uint64_t>(&out, b.alpha.size());
  }
  out += name;
  out += photo.image;
  if (billboard) out += b.displacement + b.alpha;
  Put<uint32_t>(&out, crc32c::Mask(crc32c::Value(out.data(), out.size())));
  return out;
}

Result<Photo> DecodePhoto(const std::string& data, const std::string& what) {
  auto bad = [&](const std::string& why) { return Status::Corruption(what + ": " + why); };
  if (data.size() < kFixed + 4 || std::memcmp(data.data(), kMagic, 8) != 0) return bad("not a photo file");
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  const uint32_t version = DecodeLE<uint32_t>(p + 8);
  if (version != kVersion && version != kVersionBillboard) return bad("unknown version " + std::to_string(version));
  const uint32_t crc = DecodeLE<uint32_t>(p + data.size() - 4);
  if (crc32c::Unmask(crc) != crc32c::Value(data.data(), data.size() - 4)) return bad("checksum mismatch");
  Photo photo;
  CameraInfo& c = photo.camera;
  c.id = DecodeLE<uint16_t>(p + 12);
  const size_t name_len = DecodeLE<uint16_t>(p + 14);
  c.width = DecodeLE<uint32_t>(p + 16);
  c.height = DecodeLE<uint32_t>(p + 20);
  const uint8_t* f = p + 24;
  c.fx = GetF64(f), c.fy = GetF64(f + 8), c.cx = GetF64(f + 16), c.cy = GetF64(f + 24);
  for (size_t i = 0; i < 5; ++i) c.distortion[i] = GetF64(f + 32 + 8 * i);
  for (size_t i = 0; i < 16; ++i) c.world_from_camera[i] = GetF64(f + 72 + 8 * i);
  const uint64_t image_len = DecodeLE<uint64_t>(f + 200);
  size_t head = kFixed;
  uint64_t disp_len = 0, alpha_len = 0;
  if (version == kVersionBillboard) {
    if (data.size() < kFixed + kBillboardFixed + 4) return bad("lengths do not add up to the file size");
    const uint8_t* b = p + kFixed;
    photo.billboard.scale = GetF64(b);
    for (size_t i = 0; i < 3; ++i) photo.billboard.plane[i] = GetF64(b + 8 + 8 * i);
    disp_len = DecodeLE<uint64_t>(b + 32);
    alpha_len = DecodeLE<uint64_t>(b + 40);
    head += kBillboardFixed;
    if (!(photo.billboard.scale > 0) || !std::isfinite(photo.billboard.scale)) return bad("a billboard without a scale");
  }
  // Each length is bounded before adding, so the sum cannot wrap.
  if (name_len > kMaxName || image_len > kMaxImage || disp_len > kMaxImage || alpha_len > kMaxImage ||
      head + name_len + image_len + disp_len + alpha_len + 4 != data.size()) {
    return bad("lengths do not add up to the file size");
  }
  size_t at = head;
  c.name.assign(data.data() + at, name_len);
  at += name_len;
  photo.image.assign(data.data() + at, image_len);
  at += image_len;
  photo.billboard.displacement.assign(data.data() + at, disp_len);
  at += disp_len;
  photo.billboard.alpha.assign(data.data() + at, alpha_len);
  return photo;
}

Status ValidatePhoto(const Photo& photo) {
  const CameraInfo& c = photo.camera;
  if (photo.image.empty() || photo.image.size() > kMaxImage) {
    return Status::InvalidArgument("photo: the image must hold 1 byte to 1 GiB");
  }
  if (c.width == 0 || c.height == 0 || !(c.fx > 0) || !(c.fy > 0) || !std::isfinite(c.cx) ||
      !std::isfinite(c.cy)) {
    return Status::InvalidArgument("photo: camera " + std::to_string(c.id) +
                                   " needs a size and positive focal lengths");
  }
  const PhotoBillboard& b = photo.billboard;
  if (b.scale != 0 && (!(b.scale > 0) || !std::isfinite(b.scale) || b.displacement.empty() ||
                       b.alpha.empty() || b.displacement.size() > kMaxImage ||
                       b.alpha.size() > kMaxImage ||
                       !std::all_of(b.plane.begin(), b.plane.end(), [](double v) { return std::isfinite(v); }))) {
    return Status::InvalidArgument("photo: a billboard needs a positive scale, a finite plane "
                                   "and both maps");
  }
  return Status::OK();
}

Status DatasetImpl::PutPhoto(uint32_t frame, const Photo& photo) {
  if (follower_.load()) {
    return Status::NotLeader("dataset '" + info_.name + "' is only read here: another process "
                             "holds its data directory and is the one that writes it");
  }
  HVDB_RETURN_IF_ERROR(ValidatePhoto(photo));
  const CameraInfo& c = photo.camera;
  HVDB_RETURN_IF_ERROR(env_->CreateDirs(PhotoDir(dir_)));
  // CompactPhotos removes a per-frame file only if nobody replaced it meanwhile.
  std::lock_guard<std::mutex> l(photo_mu_);
  return WriteFileAtomic(env_, PhotoDir(dir_) + "/" + PhotoFileName(frame, c.id), EncodePhoto(photo));
}

// Photos(frame): storage/photo_video.cc (per-frame files and video runs).

}  // namespace hvdb
