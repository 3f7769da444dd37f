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

constexpr char kMagic[8] = {'H', 'V', 'D', 'B', 'P', 'H', 'O', '\0'};
constexpr uint32_t kVersion = 1;
constexpr size_t kMaxName = 255;
// magic, version, camera id, name length, width, height, 4 intrinsics, 5 distortion, 16 pose,
// image length; then the name, the image and the CRC.
constexpr size_t kFixed = 8 + 4 + 2 + 2 + 4 + 4 + 8 * (4 + 5 + 16) + 8;
constexpr uint64_t kMaxImage = uint64_t{1} << 30;

void PutF64(std::string* out, double v) {
  uint64_t bits;
  std::memcpy(&bits, &v, 8);
  uint8_t b[8];
  EncodeLE<uint64_t>(b, bits);
  out->append(reinterpret_cast<const char*>(b), 8);
}
template <typename T>
void Put(std::string* out, T v) {
  uint8_t b[sizeof(T)];
  EncodeLE<T>(b, v);
  out->append(reinterpret_cast<const char*>(b), sizeof(T));
}
double GetF64(const uint8_t* p) {
  const uint64_t bits = DecodeLE<uint64_t>(p);
  double v;
  std::memcpy(&v, &bits, 8);
  return v;
}

std::string PhotoDir(const std::string& dataset_dir) { return dataset_dir + "/photos"; }

}  // namespace

std::string PhotoFileName(uint32_t frame, uint16_t camera) {
  char name[32];
  std::snprintf(name, sizeof name, "%08u-%05u.photo", frame, static_cast<unsigned>(camera));
  return name;
}

std::string EncodePhoto(const Photo& photo) {
  const CameraInfo& c = photo.camera;
  const std::string name = c.name.substr(0, kMaxName);
  std::string out(kMagic, 8);
  Put<uint32_t>(&out, kVersion);
  Put<uint16_t>(&out, c.id);
  Put<uint16_t>(&out, static_cast<uint16_t>(name.size()));
  Put<uint32_t>(&out, c.width);
  Put<uint32_t>(&out, c.height);
  for (double v : {c.fx, c.fy, c.cx, c.cy}) PutF64(&out, v);
  for (double v : c.distortion) PutF64(&out, v);
  for (double v : c.world_from_camera) PutF64(&out, v);
  Put<uint64_t>(&out, photo.image.size());
  out += name;
  out += photo.image;
  Put<uint32_t>(&out, crc32c::Mask(crc32c::Value(out.data(), out.size())));
  return out;
}

Result<Photo> DecodePhoto(const std::string& data, const std::string& what) {
  auto bad = [&](const std::string& why) { return Status::Corruption(what + ": " + why); };
  if (data.size() < kFixed + 4 || std::memcmp(data.data(), kMagic, 8) != 0) return bad("not a photo file");
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  if (DecodeLE<uint32_t>(p + 8) != kVersion) return bad("unknown version " + std::to_string(DecodeLE<uint32_t>(p + 8)));
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
  if (name_len > kMaxName || image_len > kMaxImage || kFixed + name_len + image_len + 4 != data.size()) {
    return bad("lengths do not add up to the file size");
  }
  c.name.assign(data.data() + kFixed, name_len);
  photo.image.assign(data.data() + kFixed + name_len, image_len);
  return photo;
}

Status DatasetImpl::PutPhoto(uint32_t frame, const Photo& photo) {
  if (follower_.load()) {
    return Status::NotLeader("dataset '" + info_.name + "' is only read here: another process "
                             "holds its data directory and is the one that writes it");
  }
  const CameraInfo& c = photo.camera;
  if (photo.image.empty() || photo.image.size() > kMaxImage) {
    return Status::InvalidArgument("photo: the image must hold 1 byte to 1 GiB");
  }
  if (c.width == 0 || c.height == 0 || !(c.fx > 0) || !(c.fy > 0) || !std::isfinite(c.cx) ||
      !std::isfinite(c.cy)) {
    return Status::InvalidArgument("photo: camera " + std::to_string(c.id) +
                                   " needs a size and positive focal lengths");
  }
  HVDB_RETURN_IF_ERROR(env_->CreateDirs(PhotoDir(dir_)));
  return WriteFileAtomic(env_, PhotoDir(dir_) + "/" + PhotoFileName(frame, c.id), EncodePhoto(photo));
}

Result<std::vector<Photo>> DatasetImpl::Photos(uint32_t frame) const {
  std::vector<Photo> out;
  if (!env_->Exists(PhotoDir(dir_))) return out;
  HVDB_ASSIGN_OR_RETURN(auto names, env_->ListDir(PhotoDir(dir_)));
  char prefix[16];
  std::snprintf(prefix, sizeof prefix, "%08u-", frame);
  std::sort(names.begin(), names.end());
  for (const std::string& n : names) {
    if (n.rfind(prefix, 0) != 0 || n.size() < 6 || n.substr(n.size() - 6) != ".photo") continue;
    const std::string path = PhotoDir(dir_) + "/" + n;
    auto data = ReadWholeFile(env_, path);
    if (!data.ok()) {
      if (data.status().IsNotFound()) continue;  // replaced while listing
      return data.status();
    }
    HVDB_ASSIGN_OR_RETURN(Photo photo, DecodePhoto(*data, path));
    out.push_back(std::move(photo));
  }
  return out;
}

}  // namespace hvdb
