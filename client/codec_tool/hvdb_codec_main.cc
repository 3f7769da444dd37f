// hvdb-codec: the chapter-7 point coder on files, like Draco's draco_encoder/draco_decoder.
//
//   hvdb-codec encode frame.ply frame.hv7 --qp 11 --qc 7 --qn 8 --progressive
//   hvdb-codec decode frame.hv7 out.ply [--bytes 20000]
//   hvdb-codec encode next.ply next.hv7 --reference frame.hv7    (temporal, on frame's grid)
//   hvdb-codec info frame.hv7
//   hvdb-codec compare original.ply decoded.ply
//
// Exit status: 0 success, 1 a file or stream error, 2 a usage error.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "codec/codec.h"
#include "codec/metrics.h"
#include "formats/ply.h"

namespace hvdb {
namespace {

Status ReadFile(const std::string& path, std::string* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Status::IOError(path + ": cannot open for reading");
  std::ostringstream ss;
  ss << f.rdbuf();
  if (f.bad()) return Status::IOError(path + ": read failed");
  *out = std::move(ss).str();
  return Status::OK();
}

// Writes through a temporary name and renames, so a failed run leaves no half file.
Status WriteFile(const std::string& path, const std::string& data) {
  std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) return Status::IOError(tmp + ": cannot open for writing");
    f.write(data.data(), static_cast<std::streamsize>(data.size()));
    f.flush();
    if (!f) return Status::IOError(tmp + ": write failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return Status::FromErrno(path, errno);
  return Status::OK();
}

bool IsStream(const std::string& data) { return data.size() >= 4 && data.compare(0, 4, "HV7C") == 0; }

// A reference frame: a PLY (as `decode` writes it) or an intra hvdb7 stream, decoded here.
Status LoadReference(const std::string& path, codec::Reference* ref) {
  std::string data;
  Status st = ReadFile(path, &data);
  if (!st.ok()) return st;
  if (IsStream(data)) {
    // A stream also gives its grid: an octree stream coded against it shares the grid, so the
    // cells that did not move are predicted exactly.
    codec::StreamInfo si;
    st = codec::ReadInfo(data, &si);
    if (st.ok()) st = codec::Decode(data, &ref->points);
    if (!st.ok()) return Status(st.code(), path + ": " + st.message());
    for (int a = 0; a < 3; ++a) ref->origin[a] = si.origin[a];
    ref->step = si.qp > 0 ? si.step : 0;
    ref->qp = si.qp;
    return Status::OK();
  }
  auto pts = formats::ReadPly(path);
  if (!pts.ok()) return pts.status();
  ref->points = std::move(pts).value();
  return Status::OK();
}

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void PrintStats(const codec::StreamStats& s) {
  static const char* kNames[] = {"position", "color", "normal", "covariance", "id",
                                 "frame",    "label", "camera", "flags"};
  if (s.points == 0) {
    std::printf("0 points, %zu bytes\n", s.total_bytes);
    return;
  }
  double n = static_cast<double>(s.points);
  std::printf("%llu points, %d levels, %zu bytes: %.3f bits/point%s\n",
              static_cast<unsigned long long>(s.points), s.levels, s.total_bytes,
              8.0 * s.total_bytes / n, s.temporal ? " (temporal)" : "");
  for (int g = 0; g < 9; ++g) {
    if (s.bytes_by_attribute[g] == 0) continue;
    std::printf("  %-10s %10zu bytes  %7.3f bits/point\n", kNames[g], s.bytes_by_attribute[g],
                8.0 * s.bytes_by_attribute[g] / n);
  }
  std::printf("  %-10s %10zu bytes\n", "framing", s.header_bytes);
}

int Fail(const Status& st) {
  std::fprintf(stderr, "hvdb-codec: %s\n", st.ToString().c_str());
  return 1;
}

// An input PLY; with skip_invalid its points with a NaN or infinite coordinate are left out
// and said on stderr (without it they make the read fail).
Result<std::vector<Point>> ReadInput(const std::string& path, bool skip_invalid) {
  formats::ReadOptions ro;
  ro.skip_invalid = skip_invalid;
  formats::ReadStats stats;
  auto pts = formats::ReadPly(path, ro, &stats);
  if (pts.ok() && stats.skipped_non_finite > 0) {
    std::fprintf(stderr,
                 "hvdb-codec: skipped %llu points with a NaN or infinite coordinate in %s\n",
                 static_cast<unsigned long long>(stats.skipped_non_finite), path.c_str());
  }
  return pts;
}

}  // namespace
}  // namespace hvdb

int main(int argc, char** argv) {
  using namespace hvdb;
  CLI::App app{"hvdb-codec: progressive multiresolution point coding (thesis ch. 7; docs/CODEC.md)"};
  app.require_subcommand(1);

  std::string in, out, reference, attributes = "position,color,normal";
  bool skip_invalid = false;
  const char* skip_invalid_help =
      "Leave out points with a NaN or infinite coordinate and say how many (default: an error)";
  codec::EncodeOptions eo;
  auto* enc = app.add_subcommand("encode", "Code a PLY file into an hvdb7 stream");
  enc->add_option("IN", in, "Input PLY")->required()->check(CLI::ExistingFile);
  enc->add_option("OUT", out, "Output stream")->required();
  enc->add_option("--qp", eo.qp, "Position bits over the largest extent (0: exact)")
      ->check(CLI::Range(0, 30))->capture_default_str();
  enc->add_option("--qc", eo.qc, "Colour bits of luma, chroma one less (8: lossless)")
      ->check(CLI::Range(1, 8))->capture_default_str();
  enc->add_option("--qn", eo.qn, "Normal bits per octahedral coordinate (16: lossless)")
      ->check(CLI::Range(1, 16))->capture_default_str();
  enc->add_option("--qcov", eo.qcov, "Covariance: fractional bits of log-Cholesky (0: exact)")
      ->check(CLI::Range(0, 20))->capture_default_str();
  enc->add_option("--attributes", attributes,
                  "Comma-separated: position,color,normal,covariance,id,frame,label,camera,flags,all")
      ->capture_default_str();
  enc->add_flag("--progressive", eo.progressive, "Chunked stream whose prefixes decode");
  enc->add_option("--levels", eo.levels, "Pair hierarchy levels (0: automatic)")
      ->check(CLI::Range(0, 40));
  enc->add_option("--effort", eo.effort, "Pairing effort: 0 fast, 1 fewer bits")
      ->check(CLI::Range(0, 1))->capture_default_str();
  enc->add_option("--chunk", eo.chunk, "Pairs per progressive chunk")->check(CLI::Range(64, 1 << 24))
      ->capture_default_str();
  std::string geometry = "auto";
  enc->add_option("--geometry", geometry,
                  "Position coding: octree (grids of 1-21 bits), pairs (the thesis's hierarchy, any "
                  "qp), auto (octree where it can)")
      ->check(CLI::IsMember({"auto", "octree", "pairs"}))
      ->capture_default_str();
  enc->add_option("--reference", reference,
                  "Decoded previous frame (PLY from `decode`, or an intra stream): temporal coding")
      ->check(CLI::ExistingFile);
  enc->add_flag("--skip-invalid", skip_invalid, skip_invalid_help);

  size_t bytes = 0;
  std::string dec_reference;
  bool ascii = false;
  auto* dec = app.add_subcommand("decode", "Decode an hvdb7 stream into a PLY file");
  dec->add_option("IN", in, "Input stream")->required()->check(CLI::ExistingFile);
  dec->add_option("OUT", out, "Output PLY")->required();
  dec->add_option("--bytes", bytes, "Decode only the first N bytes (progressive streams)");
  dec->add_option("--reference", dec_reference, "The reference the stream was coded against")
      ->check(CLI::ExistingFile);
  dec->add_flag("--ascii", ascii, "Write ASCII PLY");

  auto* info = app.add_subcommand("info", "Show what a stream holds");
  info->add_option("IN", in, "Input stream")->required()->check(CLI::ExistingFile);

  std::string other;
  auto* cmp = app.add_subcommand("compare", "PSNR of a decoded PLY against the original (7.5)");
  cmp->add_option("ORIGINAL", in, "Original PLY")->required()->check(CLI::ExistingFile);
  cmp->add_option("DECODED", other, "Decoded PLY")->required()->check(CLI::ExistingFile);
  cmp->add_flag("--skip-invalid", skip_invalid, skip_invalid_help);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }

  if (*enc) {
    Status st = codec::ParseAttributes(attributes, &eo.attributes);
    if (!st.ok()) {
      std::fprintf(stderr, "hvdb-codec: %s\n", st.message().c_str());
      return 2;
    }
    eo.geometry = geometry == "octree" ? codec::EncodeOptions::Geometry::kOctree
                  : geometry == "pairs" ? codec::EncodeOptions::Geometry::kPairs
                                        : codec::EncodeOptions::Geometry::kAuto;
    auto pts = ReadInput(in, skip_invalid);
    if (!pts.ok()) return Fail(pts.status());
    codec::Reference ref;
    if (!reference.empty()) {
      st = LoadReference(reference, &ref);
      if (!st.ok()) return Fail(st);
    }
    auto t0 = std::chrono::steady_clock::now();
    std::string stream;
    codec::StreamStats stats;
    st = codec::Encode(pts.value(), eo, &stream, &stats, reference.empty() ? nullptr : &ref);
    if (!st.ok()) return Fail(st);
    double secs = Seconds(t0);
    st = WriteFile(out, stream);
    if (!st.ok()) return Fail(st);
    PrintStats(stats);
    std::printf("encoded in %.3f s (%.2f M points/s)\n", secs, pts.value().size() / secs / 1e6);
    return 0;
  }
  if (*dec) {
    std::string stream;
    Status st = ReadFile(in, &stream);
    if (!st.ok()) return Fail(st);
    codec::Reference ref;
    codec::DecodeOptions opts;
    opts.max_bytes = bytes;
    if (!dec_reference.empty()) {
      st = LoadReference(dec_reference, &ref);
      if (!st.ok()) return Fail(st);
      opts.reference = &ref;
    }
    auto t0 = std::chrono::steady_clock::now();
    std::vector<Point> pts;
    codec::StreamStats stats;
    st = codec::Decode(stream, &pts, opts, &stats);
    if (!st.ok()) return Fail(Status(st.code(), in + ": " + st.message()));
    double secs = Seconds(t0);
    st = formats::WritePly(out, pts, ascii);
    if (!st.ok()) return Fail(st);
    std::printf("%zu points from %zu of %zu bytes, decoded in %.3f s (%.2f M points/s)\n",
                pts.size(), stats.total_bytes, stream.size(), secs, pts.size() / secs / 1e6);
    return 0;
  }
  if (*info) {
    std::string stream;
    Status st = ReadFile(in, &stream);
    if (!st.ok()) return Fail(st);
    codec::StreamInfo si;
    st = codec::ReadInfo(stream, &si);
    if (!st.ok()) return Fail(Status(st.code(), in + ": " + st.message()));
    std::printf("hvdb7 version %d (%s geometry), %llu points, %d levels, %s%s\nattributes: %s\n"
                "qp %d  qc %d  qn %d  qcov %d\n%zu bytes: %.3f bits/point\n",
                si.version, si.octree ? "octree" : "pair", static_cast<unsigned long long>(si.points), si.levels,
                si.progressive ? "progressive" : "fixed-rate", si.temporal ? ", temporal" : "",
                codec::AttributeNames(si.attributes).c_str(), si.qp, si.qc, si.qn, si.qcov,
                stream.size(), si.points ? 8.0 * stream.size() / si.points : 0.0);
    return 0;
  }
  if (*cmp) {
    auto a = ReadInput(in, skip_invalid);
    if (!a.ok()) return Fail(a.status());
    auto b = ReadInput(other, skip_invalid);
    if (!b.ok()) return Fail(b.status());
    codec::Quality q = codec::Compare(a.value(), b.value());
    std::printf("position PSNR %.2f dB (rms %.6g)\ncolour PSNR Y %.2f  U %.2f  V %.2f dB\n"
                "normal PSNR %.2f dB (rms %.3f degrees)\n",
                q.position_psnr, q.position_rmse, q.y_psnr, q.u_psnr, q.v_psnr, q.normal_psnr,
                q.normal_rmse_degrees);
    return 0;
  }
  return 2;
}
