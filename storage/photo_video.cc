// The video tier of photos: reading a frame's photos from per-frame files and video runs, and
// Dataset::CompactPhotos, which codes each camera's photos over a run of frames as one video.
//
// Crash safety: a run is written video first, then its index (each .tmp, synced, renamed, the
// folder synced); the index is the run's commit point. A video's name carries its CRC, so a run
// coded again under the same index name never overwrites the video the old index names (a video
// no index names is ignored and removed by the next compaction). Only then are the sources
// removed (per-frame files that nobody replaced meanwhile; superseded runs, index first). At
// every point each photo is in a per-frame file or a committed run, so a crash loses none. A per-frame file wins over a run
// (PutPhoto after compaction replaces that frame's picture).
#include "storage/photo_video.h"

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <map>
#include <set>

#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/dataset_impl.h"
#include "storage/env.h"
#include "storage/photos.h"

namespace hvdb {

namespace {

using photo_io::GetF64;
using photo_io::PhotoDir;
using photo_io::Put;
using photo_io::PutF64;

std::atomic<const PhotoVideoCodec*> g_codec{nullptr};

constexpr char kMagic[8] = {'H', 'V', 'D', 'B', 'P', 'V', 'X', '\0'};
constexpr uint32_t kVersion = 1;
constexpr size_t kMaxCodecName = 255;
constexpr uint32_t kMaxPictures = 1u << 20;
// magic, version, camera, codec name length, first, last, pictures, video bytes, video CRC,
// width, height, bound.
constexpr size_t kFixed = 8 + 4 + 2 + 2 + 4 + 4 + 4 + 8 + 4 + 4 + 4 + 8;
constexpr uint32_t kMaxSide = 1u << 16;



bool EndsWith(const std::string& s, const char* suffix) {
  const size_t n = std::strlen(suffix);
  return s.size() >= n && s.compare(s.size() - n, n, suffix) == 0;
}

// The per-frame file name's frame and camera; false if `name` is not one.
bool ParsePhotoName(const std::string& name, uint32_t* frame, uint16_t* camera) {
  unsigned f = 0, c = 0;
  int used = 0;
  if (name.size() != 20 || !EndsWith(name, ".photo")) return false;
  if (std::sscanf(name.c_str(), "%8u-%5u.photo%n", &f, &c, &used) != 2 || used != 20) return false;
  if (c > 0xFFFF) return false;
  *frame = f;
  *camera = static_cast<uint16_t>(c);
  return true;
}

struct RunName {
  std::string name;  // the index's
  uint32_t first = 0, last = 0;
  uint16_t camera = 0;
};

// The photo folder's per-frame files and run indexes, by name.
struct Listing {
  std::map<std::pair<uint16_t, uint32_t>, std::string> singles;  // (camera, frame) -> name
  std::vector<RunName> runs;                                      // by name
  std::set<std::string> names;
};

Result<Listing> ListPhotos(Env* env, const std::string& dir) {
  Listing out;
  if (!env->Exists(dir)) return out;
  HVDB_ASSIGN_OR_RETURN(auto names, env->ListDir(dir));
  std::sort(names.begin(), names.end());
  for (const std::string& n : names) {
    out.names.insert(n);
    uint32_t f, l;
    uint16_t c;
    if (ParsePhotoName(n, &f, &c)) {
      out.singles[{c, f}] = n;
    } else if (ParsePhotoVideoName(n, &f, &l, &c)) {
      out.runs.push_back(RunName{n, f, l, c});
    }
  }
  return out;
}

// The video an index names: its own name with the video's CRC, so that a run coded again
// under the same index name writes a new video file and the index stays the commit point.
std::string VideoOf(const std::string& index_name, uint32_t video_crc) {
  char tail[16];
  std::snprintf(tail, sizeof tail, "-%08x.ivf", video_crc);
  return index_name.substr(0, index_name.size() - 4) + tail;
}

// The run's video file, checked against its index. Corruption names the file.
Result<std::string> ReadRunVideo(Env* env, const std::string& path, const PhotoVideoIndex& index) {
  auto video = ReadWholeFile(env, path);
  if (!video.ok()) {
    if (video.status().IsNotFound()) {
      return Status::Corruption(path + ": the video file of a photo run is missing");
    }
    return video.status();
  }
  if (video->size() != index.video_bytes ||
      crc32c::Value(video->data(), video->size()) != index.video_crc) {
    return Status::Corruption(path + ": checksum mismatch (the photo run's video file is damaged)");
  }
  return std::move(*video);
}

}  // namespace

void SetPhotoVideoCodec(const PhotoVideoCodec* codec) { g_codec.store(codec); }
const PhotoVideoCodec* GetPhotoVideoCodec() { return g_codec.load(); }

std::string PhotoVideoIndexName(uint32_t first, uint32_t last, uint16_t camera) {
  char name[48];
  std::snprintf(name, sizeof name, "%08u-%08u-%05u.pvx", first, last, static_cast<unsigned>(camera));
  return name;
}

std::string PhotoVideoFileName(uint32_t first, uint32_t last, uint16_t camera, uint32_t video_crc) {
  return VideoOf(PhotoVideoIndexName(first, last, camera), video_crc);
}

bool ParsePhotoVideoName(const std::string& name, uint32_t* first, uint32_t* last,
                         uint16_t* camera) {
  unsigned f = 0, l = 0, c = 0;
  int used = 0;
  if (name.size() != 27 || !EndsWith(name, ".pvx")) return false;
  if (std::sscanf(name.c_str(), "%8u-%8u-%5u.pvx%n", &f, &l, &c, &used) != 3 || used != 27) {
    return false;
  }
  if (c > 0xFFFF || f > l) return false;
  *first = f;
  *last = l;
  *camera = static_cast<uint16_t>(c);
  return true;
}

std::string EncodePhotoVideoIndex(const PhotoVideoIndex& index) {
  const std::string codec = index.codec.substr(0, kMaxCodecName);
  std::string out(kMagic, 8);
  Put<uint32_t>(&out, kVersion);
  Put<uint16_t>(&out, index.camera);
  Put<uint16_t>(&out, static_cast<uint16_t>(codec.size()));
  Put<uint32_t>(&out, index.first);
  Put<uint32_t>(&out, index.last);
  Put<uint32_t>(&out, static_cast<uint32_t>(index.entries.size()));
  Put<uint64_t>(&out, index.video_bytes);
  Put<uint32_t>(&out, index.video_crc);
  Put<uint32_t>(&out, index.width);
  Put<uint32_t>(&out, index.height);
  PutF64(&out, index.min_psnr);
  out += codec;
  for (const PhotoVideoEntry& e : index.entries) {
    const std::string meta = EncodePhoto(e.meta);  // the image is empty: the video holds it
    Put<uint32_t>(&out, e.frame);
    PutF64(&out, e.psnr);
    Put<uint32_t>(&out, static_cast<uint32_t>(meta.size()));
    out += meta;
  }
  Put<uint32_t>(&out, crc32c::Mask(crc32c::Value(out.data(), out.size())));
  return out;
}

Result<PhotoVideoIndex> DecodePhotoVideoIndex(const std::string& data, const std::string& what) {
  auto bad = [&](const std::string& why) { return Status::Corruption(what + ": " + why); };
  if (data.size() < kFixed + 4 || std::memcmp(data.data(), kMagic, 8) != 0) {
    return bad("not a photo run index");
  }
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  const uint32_t version = DecodeLE<uint32_t>(p + 8);
  if (version != kVersion) return bad("unknown version " + std::to_string(version));
  if (crc32c::Unmask(DecodeLE<uint32_t>(p + data.size() - 4)) !=
      crc32c::Value(data.data(), data.size() - 4)) {
    return bad("checksum mismatch");
  }
  PhotoVideoIndex index;
  index.camera = DecodeLE<uint16_t>(p + 12);
  const size_t codec_len = DecodeLE<uint16_t>(p + 14);
  index.first = DecodeLE<uint32_t>(p + 16);
  index.last = DecodeLE<uint32_t>(p + 20);
  const uint32_t count = DecodeLE<uint32_t>(p + 24);
  index.video_bytes = DecodeLE<uint64_t>(p + 28);
  index.video_crc = DecodeLE<uint32_t>(p + 36);
  index.width = DecodeLE<uint32_t>(p + 40);
  index.height = DecodeLE<uint32_t>(p + 44);
  index.min_psnr = GetF64(p + 48);
  const size_t end = data.size() - 4;
  if (codec_len > kMaxCodecName || count == 0 || count > kMaxPictures || kFixed + codec_len > end) {
    return bad("lengths do not add up to the file size");
  }
  if (index.width == 0 || index.height == 0 || index.width > kMaxSide || index.height > kMaxSide) {
    return bad("a picture size of " + std::to_string(index.width) + "x" +
               std::to_string(index.height));
  }
  index.codec.assign(data.data() + kFixed, codec_len);
  size_t at = kFixed + codec_len;
  for (uint32_t i = 0; i < count; ++i) {
    if (end - at < 16) return bad("lengths do not add up to the file size");
    PhotoVideoEntry e;
    e.frame = DecodeLE<uint32_t>(p + at);
    e.psnr = GetF64(p + at + 4);
    const uint32_t len = DecodeLE<uint32_t>(p + at + 12);
    at += 16;
    if (len > end - at) return bad("lengths do not add up to the file size");
    HVDB_ASSIGN_OR_RETURN(e.meta, DecodePhoto(data.substr(at, len), what + " (picture " +
                                                                        std::to_string(i) + ")"));
    at += len;
    if ((!index.entries.empty() && e.frame <= index.entries.back().frame) ||
        e.frame < index.first || e.frame > index.last || e.meta.camera.id != index.camera) {
      return bad("picture " + std::to_string(i) + " is out of order or of another camera");
    }
    index.entries.push_back(std::move(e));
  }
  if (at != end) return bad("lengths do not add up to the file size");
  return index;
}

// Camera `camera`'s photo of `frame` from the run whose index is `name`; nullopt when the run
// has no picture of that frame (or the index was removed meanwhile: *gone).
Result<std::optional<Photo>> DatasetImpl::PhotoFromRun(const std::string& name, uint32_t frame,
                                                       bool* gone) const {
  const std::string dir = PhotoDir(dir_);
  auto data = ReadWholeFile(env_, dir + "/" + name);
  if (!data.ok()) {
    if (data.status().IsNotFound()) {
      *gone = true;
      return std::optional<Photo>();
    }
    return data.status();
  }
  HVDB_ASSIGN_OR_RETURN(PhotoVideoIndex index, DecodePhotoVideoIndex(*data, dir + "/" + name));
  auto it = std::find_if(index.entries.begin(), index.entries.end(),
                         [&](const PhotoVideoEntry& e) { return e.frame == frame; });
  if (it == index.entries.end()) return std::optional<Photo>();
  const std::string video_path = dir + "/" + VideoOf(name, index.video_crc);
  const PhotoVideoCodec* codec = GetPhotoVideoCodec();
  if (codec == nullptr) {
    return Status::Unsupported(video_path + ": photos coded as video need a video codec, and "
                               "this program has none (link hvdb_media and call "
                               "media::InstallPhotoVideoCodec)");
  }
  auto video = ReadRunVideo(env_, video_path, index);
  if (!video.ok()) {
    // A compaction removed or replaced the run after we read its index: read again.
    auto again = ReadWholeFile(env_, dir + "/" + name);
    if (!again.ok() || *again != *data) {
      *gone = true;
      return std::optional<Photo>();
    }
    return video.status();
  }
  Photo photo = std::move(it->meta);
  HVDB_ASSIGN_OR_RETURN(photo.image, codec->Decode(*video, static_cast<uint32_t>(
                                                              it - index.entries.begin()),
                                                   index.width, index.height, video_path));
  return std::optional<Photo>(std::move(photo));
}

Result<std::optional<Photo>> DatasetImpl::PhotoOf(uint32_t frame, uint16_t camera) const {
  // A compaction may remove a source between the listing and the read: list again.
  for (int attempt = 0; attempt < 5; ++attempt) {
    HVDB_ASSIGN_OR_RETURN(Listing l, ListPhotos(env_, PhotoDir(dir_)));
    bool gone = false;
    auto single = l.singles.find({camera, frame});
    if (single != l.singles.end()) {
      const std::string path = PhotoDir(dir_) + "/" + single->second;
      auto data = ReadWholeFile(env_, path);
      if (data.ok()) {
        HVDB_ASSIGN_OR_RETURN(Photo photo, DecodePhoto(*data, path));
        return std::optional<Photo>(std::move(photo));
      }
      if (!data.status().IsNotFound()) return data.status();
      continue;
    }
    // Runs may overlap only while a compaction replaces one: the newest name first.
    for (auto it = l.runs.rbegin(); it != l.runs.rend() && !gone; ++it) {
      if (it->camera != camera || frame < it->first || frame > it->last) continue;
      HVDB_ASSIGN_OR_RETURN(auto photo, PhotoFromRun(it->name, frame, &gone));
      if (photo) return photo;
    }
    if (!gone) return std::optional<Photo>();
  }
  return Status::IOError("photos of frame " + std::to_string(frame) + " camera " +
                         std::to_string(camera) + " kept moving while read; try again");
}

Result<std::vector<Photo>> DatasetImpl::Photos(uint32_t frame) const {
  std::vector<Photo> out;
  HVDB_ASSIGN_OR_RETURN(Listing l, ListPhotos(env_, PhotoDir(dir_)));
  std::set<uint16_t> cameras;
  for (const auto& [key, name] : l.singles) {
    if (key.second == frame) cameras.insert(key.first);
  }
  for (const RunName& r : l.runs) {
    if (frame >= r.first && frame <= r.last) cameras.insert(r.camera);
  }
  for (uint16_t c : cameras) {
    HVDB_ASSIGN_OR_RETURN(auto photo, PhotoOf(frame, c));
    if (photo) out.push_back(std::move(*photo));
  }
  return out;
}

// Codes `photos` (camera's, by frame) as runs, one per stretch of frames at one picture size,
// each written video first, then index; adds both file names to *written.
Status DatasetImpl::WriteRuns(uint16_t camera, const std::map<uint32_t, Photo>& photos,
                              std::set<std::string>* written, CompactInfo* info) {
  const PhotoVideoCodec* codec = GetPhotoVideoCodec();
  const std::string dir = PhotoDir(dir_);
  // One run per stretch of frames at one picture size.
  for (auto begin = photos.begin(); begin != photos.end();) {
    auto end = begin;
    std::vector<std::string_view> images;
    while (end != photos.end() && end->second.camera.width == begin->second.camera.width &&
           end->second.camera.height == begin->second.camera.height) {
      images.push_back(end->second.image);
      ++end;
    }
    const uint32_t run_first = begin->first, run_last = std::prev(end)->first;
    const std::string what = "compact --photos: camera " + std::to_string(camera) +
                             ", frames " + std::to_string(run_first) + "-" +
                             std::to_string(run_last);
    auto coded = codec->Encode(images, kPhotoVideoMinPsnr);
    if (!coded.ok()) return Status(coded.status().code(), what + ": " + coded.status().message());
    if (coded->psnr.size() != images.size() || coded->video.empty()) {
      return Status::Internal(what + ": the codec returned " + std::to_string(coded->psnr.size()) +
                              " pictures for " + std::to_string(images.size()));
    }
    PhotoVideoIndex index;
    index.camera = camera;
    index.first = run_first;
    index.last = run_last;
    index.video_bytes = coded->video.size();
    index.video_crc = crc32c::Value(coded->video.data(), coded->video.size());
    index.min_psnr = kPhotoVideoMinPsnr;
    index.codec = coded->codec;
    index.width = coded->width;
    index.height = coded->height;
    size_t i = 0;
    for (auto it = begin; it != end; ++it, ++i) {
      if (!(coded->psnr[i] >= kPhotoVideoMinPsnr)) {
        return Status::Internal(what + ": frame " + std::to_string(it->first) + " came out at " +
                                std::to_string(coded->psnr[i]) + " dB, under the bound");
      }
      PhotoVideoEntry e;
      e.frame = it->first;
      e.psnr = coded->psnr[i];
      e.meta = it->second;
      e.meta.image.clear();
      index.entries.push_back(std::move(e));
      info->photo_min_psnr = info->photo_min_psnr == 0 ? coded->psnr[i]
                                                     : std::min(info->photo_min_psnr, coded->psnr[i]);
    }
    const std::string video_name =
        PhotoVideoFileName(run_first, run_last, camera, index.video_crc);
    HVDB_RETURN_IF_ERROR(WriteFileAtomic(env_, dir + "/" + video_name, coded->video));
    written->insert(video_name);
    const std::string index_name = PhotoVideoIndexName(run_first, run_last, camera);
    HVDB_RETURN_IF_ERROR(WriteFileAtomic(env_, dir + "/" + index_name,
                                         EncodePhotoVideoIndex(index)));
    written->insert(index_name);
    info->photo_runs += 1;
    info->photo_pictures += static_cast<uint32_t>(index.entries.size());
    info->photo_bytes_after += coded->video.size();
    begin = end;
  }
  return Status::OK();
}

Result<CompactInfo> DatasetImpl::CompactPhotos(uint32_t first, uint32_t last) {
  HVDB_RETURN_IF_ERROR(CheckCompact(first, last));
  const PhotoVideoCodec* codec = GetPhotoVideoCodec();
  if (codec == nullptr) {
    return Status::Unsupported("compact --photos: this program has no video codec (link "
                               "hvdb_media and call media::InstallPhotoVideoCodec)");
  }
  std::lock_guard<std::mutex> serial(photo_compact_mu_);
  const std::string dir = PhotoDir(dir_);
  HVDB_ASSIGN_OR_RETURN(Listing l, ListPhotos(env_, dir));
  CompactInfo info;
  info.photo_min_psnr = 0;
  std::set<uint16_t> cameras;
  for (const auto& [key, name] : l.singles) cameras.insert(key.first);
  for (const RunName& r : l.runs) cameras.insert(r.camera);
  for (uint16_t camera : cameras) {
    // The per-frame files in the range, and the runs holding one of them (an edit after a
    // compaction): those runs are coded again with their edits, widening the range over them.
    // Other runs stay as they are (coding decoded pictures again would lose more).
    uint32_t lo = first, hi = last;
    std::map<uint32_t, std::string> singles;  // frame -> name
    std::vector<const RunName*> touched, kept;
    for (bool grew = true; grew;) {
      grew = false;
      singles.clear();
      for (auto it = l.singles.lower_bound({camera, lo});
           it != l.singles.end() && it->first.first == camera && it->first.second <= hi; ++it) {
        singles[it->first.second] = it->second;
      }
      touched.clear();
      kept.clear();
      for (const RunName& r : l.runs) {
        if (r.camera != camera || r.first > hi || r.last < lo) continue;
        auto s = singles.lower_bound(r.first);
        const bool edited = s != singles.end() && s->first <= r.last;
        (edited ? touched : kept).push_back(&r);
        if (edited && (r.first < lo || r.last > hi)) {
          lo = std::min(lo, r.first), hi = std::max(hi, r.last), grew = true;
        }
      }
    }
    if (singles.empty()) {
      info.photo_already += kept.empty() ? 0 : 1;
      continue;
    }
    // Where each frame's picture is: a per-frame file wins over a run ("": the file).
    std::map<uint32_t, std::string> source;
    std::vector<std::string> old_videos;
    for (const RunName* r : touched) {
      HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env_, dir + "/" + r->name));
      HVDB_ASSIGN_OR_RETURN(PhotoVideoIndex index, DecodePhotoVideoIndex(data, dir + "/" + r->name));
      info.photo_bytes_before += index.video_bytes;
      old_videos.push_back(VideoOf(r->name, index.video_crc));
      for (const PhotoVideoEntry& e : index.entries) source.emplace(e.frame, r->name);
    }
    for (const auto& [frame, name] : singles) source[frame] = "";
    // A new run must not reach over a run kept between its frames.
    auto kept_between = [&](uint32_t a, uint32_t b) {
      return std::any_of(kept.begin(), kept.end(),
                         [&](const RunName* r) { return r->first > a && r->first < b; });
    };
    std::map<uint32_t, uint32_t> single_crc;  // of the per-frame files read
    std::set<std::string> written;  // file names of the new runs (indexes and videos)
    // At most kPhotoVideoMaxPictures photos in memory at once: a run's.
    for (auto chunk = source.begin(); chunk != source.end();) {
      std::map<uint32_t, Photo> photos;
      for (size_t n = 0; chunk != source.end() && n < kPhotoVideoMaxPictures; ++chunk, ++n) {
        const uint32_t frame = chunk->first;
        if (!photos.empty() && kept_between(photos.rbegin()->first, frame)) break;
        if (chunk->second.empty()) {
          const std::string path = dir + "/" + singles[frame];
          HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env_, path));
          HVDB_ASSIGN_OR_RETURN(Photo photo, DecodePhoto(data, path));
          single_crc[frame] = crc32c::Value(data.data(), data.size());
          info.photo_bytes_before += photo.image.size();
          photos[frame] = std::move(photo);
        } else {
          bool gone = false;
          HVDB_ASSIGN_OR_RETURN(auto photo, PhotoFromRun(chunk->second, frame, &gone));
          if (!photo) {
            return Status::Corruption(dir + "/" + chunk->second + ": frame " +
                                      std::to_string(frame) + " went missing during compaction");
          }
          photos[frame] = std::move(*photo);
        }
      }
      HVDB_RETURN_IF_ERROR(WriteRuns(camera, photos, &written, &info));
    }
    // Retire the sources now in the new runs; a per-frame file replaced meanwhile stays (it
    // wins over the run).
    {
      std::lock_guard<std::mutex> l2(photo_mu_);
      for (const auto& [frame, name] : singles) {
        auto data = ReadWholeFile(env_, dir + "/" + name);
        if (!data.ok() || crc32c::Value(data->data(), data->size()) != single_crc[frame]) continue;
        HVDB_RETURN_IF_ERROR(env_->Remove(dir + "/" + name));
      }
    }
    // Indexes first: a run's video goes only once no index names it.
    for (const RunName* r : touched) {
      if (written.count(r->name) == 0) HVDB_RETURN_IF_ERROR(env_->Remove(dir + "/" + r->name));
    }
    for (const std::string& v : old_videos) {
      if (written.count(v) == 0) HVDB_RETURN_IF_ERROR(env_->Remove(dir + "/" + v));
    }
    HVDB_RETURN_IF_ERROR(env_->SyncDir(dir));
  }
  // Videos no index names (a crash before their index, or before their removal) and left-over
  // .tmp files.
  HVDB_ASSIGN_OR_RETURN(Listing now, ListPhotos(env_, dir));
  std::set<std::string> named;
  for (const RunName& r : now.runs) {
    HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env_, dir + "/" + r.name));
    HVDB_ASSIGN_OR_RETURN(PhotoVideoIndex index, DecodePhotoVideoIndex(data, dir + "/" + r.name));
    named.insert(VideoOf(r.name, index.video_crc));
  }
  bool removed = false;
  for (const std::string& n : now.names) {
    const bool orphan = EndsWith(n, ".ivf") && named.count(n) == 0;
    if (orphan || (EndsWith(n, ".ivf.tmp") || EndsWith(n, ".pvx.tmp"))) {
      HVDB_RETURN_IF_ERROR(env_->Remove(dir + "/" + n));
      removed = true;
    }
  }
  if (removed) HVDB_RETURN_IF_ERROR(env_->SyncDir(dir));
  return info;
}

}  // namespace hvdb
