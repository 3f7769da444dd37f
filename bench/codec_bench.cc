// codec-bench: the chapter-7 point coder (codec/) against Draco (Debian's libdraco) on the same
// points, with the thesis's metrics (7.5): bits per point per attribute against PSNR, as
// rate-distortion curves and as bit ratios at equal PSNR; progressive against fixed-rate
// streams and the quality of progressive prefixes; temporal against intra coding of the
// Panoptic sequence; encode and decode speed. Writes JSON (bench/README.md) and, with
// --plots, PNG curves through bench/codec_plot.py.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include <draco/compression/decode.h>
#include <draco/compression/encode.h>
#include <draco/point_cloud/point_cloud_builder.h>
#include <nanoflann.hpp>

#include "bench/codec_time.h"
#include "codec/codec.h"
#include "codec/metrics.h"
#include "formats/ply.h"

namespace {

using hvdb::Point;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

double Secs(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

[[noreturn]] void Die(const std::string& what) {
  std::fprintf(stderr, "codec-bench: %s\n", what.c_str());
  std::exit(1);
}
void Check(const hvdb::Status& st, const std::string& what) {
  if (!st.ok()) Die(what + ": " + st.ToString());
}

struct DataSet {
  std::string name;
  std::vector<Point> points;
  bool color = true, normal = true;
};

struct NormalCloud {
  const std::vector<Point>* p;
  size_t kdtree_get_point_count() const { return p->size(); }
  float kdtree_get_pt(uint32_t i, size_t d) const {
    return d == 0 ? (*p)[i].x : d == 1 ? (*p)[i].y : (*p)[i].z;
  }
  template <class B>
  bool kdtree_get_bbox(B&) const { return false; }
};

// Bunny: positions of the merged scan; normals by PCA over the 12 nearest neighbours,
// oriented away from the centroid (the model is closed enough for that).
void AddNormals(std::vector<Point>* pts) {
  NormalCloud cloud{pts};
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, NormalCloud>,
                                                   NormalCloud, 3, uint32_t>;
  Tree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  double c[3] = {0, 0, 0};
  for (const Point& p : *pts) c[0] += p.x, c[1] += p.y, c[2] += p.z;
  for (double& v : c) v /= static_cast<double>(pts->size());
  for (Point& p : *pts) {
    uint32_t idx[12];
    float d2[12];
    nanoflann::KNNResultSet<float, uint32_t> rs(12);
    rs.init(idx, d2);
    float q[3] = {p.x, p.y, p.z};
    tree.findNeighbors(rs, q, nanoflann::SearchParams());
    double m[3] = {0, 0, 0}, C[3][3] = {};
    for (size_t k = 0; k < rs.size(); ++k) {
      const Point& o = (*pts)[idx[k]];
      m[0] += o.x, m[1] += o.y, m[2] += o.z;
    }
    for (double& v : m) v /= static_cast<double>(rs.size());
    for (size_t k = 0; k < rs.size(); ++k) {
      const Point& o = (*pts)[idx[k]];
      double d[3] = {o.x - m[0], o.y - m[1], o.z - m[2]};
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) C[a][b] += d[a] * d[b];
    }
    // Smallest eigenvector by inverse power iteration on C + eps I.
    double v[3] = {1, 1, 1};
    for (int it = 0; it < 30; ++it) {
      double A[3][3];
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) A[a][b] = C[a][b] + (a == b ? 1e-12 : 0);
      double det = A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1]) -
                   A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0]) +
                   A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0]);
      if (std::abs(det) < 1e-30) break;
      double inv[3][3] = {
          {(A[1][1] * A[2][2] - A[1][2] * A[2][1]) / det, (A[0][2] * A[2][1] - A[0][1] * A[2][2]) / det,
           (A[0][1] * A[1][2] - A[0][2] * A[1][1]) / det},
          {(A[1][2] * A[2][0] - A[1][0] * A[2][2]) / det, (A[0][0] * A[2][2] - A[0][2] * A[2][0]) / det,
           (A[0][2] * A[1][0] - A[0][0] * A[1][2]) / det},
          {(A[1][0] * A[2][1] - A[1][1] * A[2][0]) / det, (A[0][1] * A[2][0] - A[0][0] * A[2][1]) / det,
           (A[0][0] * A[1][1] - A[0][1] * A[1][0]) / det}};
      double w[3];
      for (int a = 0; a < 3; ++a) w[a] = inv[a][0] * v[0] + inv[a][1] * v[1] + inv[a][2] * v[2];
      double len = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
      for (int a = 0; a < 3; ++a) v[a] = w[a] / len;
    }
    double out = (p.x - c[0]) * v[0] + (p.y - c[1]) * v[1] + (p.z - c[2]) * v[2];
    if (out < 0) v[0] = -v[0], v[1] = -v[1], v[2] = -v[2];
    p.normal_oct = hvdb::EncodeNormal(static_cast<float>(v[0]), static_cast<float>(v[1]),
                                      static_cast<float>(v[2]));
    p.flags |= hvdb::kFlagHasNormal;
  }
}

// ---- Draco on the same points --------------------------------------------------------------

struct DracoSettings {
  int qp = 11;
  int qc = 0;   // 0: colours as 8-bit integers (lossless); else float colours quantised
  int qn = 0;   // 0: no normals
  bool color = false;
  int speed = 0;  // 0 = best compression (cl 10), 3 = Draco's default (cl 7)
};

std::string DracoEncode(const std::vector<Point>& pts, const DracoSettings& s) {
  draco::PointCloudBuilder b;
  b.Start(static_cast<draco::PointIndex::ValueType>(pts.size()));
  const int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  int col = -1, nrm = -1;
  if (s.color) {
    col = b.AddAttribute(draco::GeometryAttribute::COLOR, 3,
                         s.qc ? draco::DT_FLOAT32 : draco::DT_UINT8);
  }
  if (s.qn) nrm = b.AddAttribute(draco::GeometryAttribute::NORMAL, 3, draco::DT_FLOAT32);
  for (size_t i = 0; i < pts.size(); ++i) {
    const Point& p = pts[i];
    draco::PointIndex pi(static_cast<draco::PointIndex::ValueType>(i));
    const float xyz[3] = {p.x, p.y, p.z};
    b.SetAttributeValueForPoint(pos, pi, xyz);
    if (col >= 0) {
      if (s.qc) {
        const float rgb[3] = {float(p.r), float(p.g), float(p.b)};
        b.SetAttributeValueForPoint(col, pi, rgb);
      } else {
        const uint8_t rgb[3] = {p.r, p.g, p.b};
        b.SetAttributeValueForPoint(col, pi, rgb);
      }
    }
    if (nrm >= 0) {
      auto n = hvdb::DecodeNormal(p.normal_oct);
      b.SetAttributeValueForPoint(nrm, pi, n.data());
    }
  }
  auto pc = b.Finalize(false);
  draco::Encoder enc;
  enc.SetAttributeQuantization(draco::GeometryAttribute::POSITION, s.qp);
  if (s.color && s.qc) enc.SetAttributeQuantization(draco::GeometryAttribute::COLOR, s.qc);
  if (s.qn) enc.SetAttributeQuantization(draco::GeometryAttribute::NORMAL, s.qn);
  enc.SetSpeedOptions(s.speed, s.speed);
  draco::EncoderBuffer buf;
  auto st = enc.EncodePointCloudToBuffer(*pc, &buf);
  if (!st.ok()) Die(std::string("draco encode: ") + st.error_msg());
  return std::string(buf.data(), buf.size());
}

std::vector<Point> DracoDecode(const std::string& data) {
  draco::DecoderBuffer buf;
  buf.Init(data.data(), data.size());
  draco::Decoder dec;
  auto res = dec.DecodePointCloudFromBuffer(&buf);
  if (!res.ok()) Die("draco decode failed");
  auto pc = std::move(res).value();
  const auto* pos = pc->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  const auto* col = pc->GetNamedAttribute(draco::GeometryAttribute::COLOR);
  const auto* nrm = pc->GetNamedAttribute(draco::GeometryAttribute::NORMAL);
  std::vector<Point> out(pc->num_points());
  for (draco::PointIndex i(0); i < pc->num_points(); ++i) {
    Point& p = out[i.value()];
    float xyz[3];
    pos->GetMappedValue(i, xyz);
    p.x = xyz[0], p.y = xyz[1], p.z = xyz[2];
    if (col) {
      if (col->data_type() == draco::DT_FLOAT32) {
        float rgb[3];
        col->GetMappedValue(i, rgb);
        p.r = static_cast<uint8_t>(std::clamp(std::lround(rgb[0]), 0L, 255L));
        p.g = static_cast<uint8_t>(std::clamp(std::lround(rgb[1]), 0L, 255L));
        p.b = static_cast<uint8_t>(std::clamp(std::lround(rgb[2]), 0L, 255L));
      } else {
        uint8_t rgb[3];
        col->GetMappedValue(i, rgb);
        p.r = rgb[0], p.g = rgb[1], p.b = rgb[2];
      }
    }
    if (nrm) {
      float n[3];
      nrm->GetMappedValue(i, n);
      p.normal_oct = hvdb::EncodeNormal(n[0], n[1], n[2]);
      p.flags |= hvdb::kFlagHasNormal;
    }
  }
  return out;
}

// ---- ours ------------------------------------------------------------------------------------

std::string OursEncode(const std::vector<Point>& pts, const hvdb::codec::EncodeOptions& o,
                       hvdb::codec::StreamStats* stats = nullptr,
                       const hvdb::codec::Reference* ref = nullptr) {
  std::string s;
  Check(hvdb::codec::Encode(pts, o, &s, stats, ref), "encode");
  return s;
}
std::vector<Point> OursDecode(const std::string& s, const hvdb::codec::Reference* ref = nullptr,
                              size_t max_bytes = 0) {
  std::vector<Point> out;
  hvdb::codec::DecodeOptions o;
  o.reference = ref;
  o.max_bytes = max_bytes;
  Check(hvdb::codec::Decode(s, &out, o), "decode");
  return out;
}

double Bpp(size_t bytes, size_t n) { return 8.0 * static_cast<double>(bytes) / static_cast<double>(n); }

// Our bits per point at the PSNR of `at`, interpolated along our curve (NaN outside it).
double BppAt(const json& curve, double psnr) {
  std::vector<std::pair<double, double>> pts;
  for (const auto& p : curve) pts.push_back({p["psnr"].get<double>(), p["bpp"].get<double>()});
  std::sort(pts.begin(), pts.end());
  for (size_t i = 0; i + 1 < pts.size(); ++i) {
    if (psnr >= pts[i].first && psnr <= pts[i + 1].first) {
      double t = (psnr - pts[i].first) / std::max(1e-9, pts[i + 1].first - pts[i].first);
      return pts[i].second + t * (pts[i + 1].second - pts[i].second);
    }
  }
  return std::nan("");
}

json EqualPsnr(const json& ours, const json& draco) {
  json out = json::array();
  std::vector<double> ratios;
  for (const auto& d : draco) {
    double psnr = d["psnr"].get<double>();
    double b = BppAt(ours, psnr);
    if (std::isnan(b)) continue;
    double r = b / d["bpp"].get<double>();
    ratios.push_back(r);
    out.push_back({{"psnr", psnr}, {"draco_bpp", d["bpp"]}, {"ours_bpp", b}, {"ratio", r}});
  }
  std::sort(ratios.begin(), ratios.end());
  return {{"points", out},
          {"median_ratio", ratios.empty() ? json(nullptr) : json(ratios[ratios.size() / 2])}};
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"codec-bench: hvdb7 (thesis ch. 7) against Draco, rate-distortion and speed"};
  std::string out = "codec.json", shared = HVDB_SHARED_DATA, scratch = "/tmp";
  bool quick = false, plots = false;
  int frames = 16, reps = 3;
  std::vector<std::string> extra;
  app.add_option("--out", out, "JSON output file")->capture_default_str();
  app.add_flag("--quick", quick, "two frames, fewer settings (CI smoke run)");
  app.add_flag("--plots", plots, "write PNG rate-distortion plots next to the JSON");
  app.add_option("--frames", frames, "Panoptic frames")->check(CLI::Range(2, 16))->capture_default_str();
  app.add_option("--repetitions", reps, "timing runs (median)")->check(CLI::Range(1, 20))
      ->capture_default_str();
  app.add_option("--shared-data", shared, "the shared data folder")->capture_default_str();
  app.add_option("--ply", extra, "more inputs, NAME=PATH (metres), e.g. ingested frames");
  app.add_option("--scratch", scratch, "folder for the generated recording")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (quick) frames = 2, reps = 1;

  std::vector<DataSet> sets;
  std::vector<std::vector<Point>> panoptic;
  for (int f = 0; f < frames; ++f) {
    hvdb::formats::ReadOptions ro;
    ro.scale = 0.01;
    char path[512];
    std::snprintf(path, sizeof path,
                  "%s/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/ptcloud_hd%08d.ply",
                  shared.c_str(), 380 + f);
    auto r = hvdb::formats::ReadPly(path, ro);
    if (!r.ok()) Die(r.status().ToString());
    panoptic.push_back(std::move(r).value());
  }
  sets.push_back({"panoptic380", panoptic[0], true, true});
  {
    auto r = hvdb::formats::ReadPly(shared + "/stanford-bunny/reconstruction/bun_zipper.ply");
    if (!r.ok()) Die(r.status().ToString());
    DataSet d{"bunny", std::move(r).value(), false, true};
    AddNormals(&d.points);
    sets.push_back(std::move(d));
  }
  for (const std::string& e : extra) {
    size_t eq = e.find('=');
    if (eq == std::string::npos) Die("--ply takes NAME=PATH");
    auto r = hvdb::formats::ReadPly(e.substr(eq + 1));
    if (!r.ok()) Die(r.status().ToString());
    DataSet d{e.substr(0, eq), std::move(r).value(), true, false};
    d.normal = std::any_of(d.points.begin(), d.points.end(),
                           [](const Point& p) { return p.flags & hvdb::kFlagHasNormal; });
    sets.push_back(std::move(d));
  }

  const std::vector<int> qps = quick ? std::vector<int>{9, 11, 13} : std::vector<int>{8, 9, 10, 11, 12, 13, 14};
  const std::vector<int> qcs = quick ? std::vector<int>{5, 8} : std::vector<int>{3, 4, 5, 6, 7, 8};
  const std::vector<int> qns = quick ? std::vector<int>{6, 10} : std::vector<int>{5, 6, 7, 8, 10, 12};
  const int qp_attr = 11;
  json rd = json::object(), summary = json::object();
  for (const DataSet& ds : sets) {
    const size_t n = ds.points.size();
    std::fprintf(stderr, "%s: %zu points\n", ds.name.c_str(), n);
    json& D = rd[ds.name];
    // Positions alone.
    for (int qp : qps) {
      for (bool prog : {false, true}) {
        hvdb::codec::EncodeOptions o;
        o.qp = qp;
        o.attributes = hvdb::codec::kPosition;
        o.progressive = prog;
        std::string s = OursEncode(ds.points, o);
        auto q = hvdb::codec::Compare(ds.points, OursDecode(s));
        D["position"][prog ? "ours_progressive" : "ours_fixed"].push_back(
            {{"qp", qp}, {"bpp", Bpp(s.size(), n)}, {"psnr", q.position_psnr}});
      }
      for (int speed : {0, 3}) {
        DracoSettings d;
        d.qp = qp;
        d.speed = speed;
        std::string s = DracoEncode(ds.points, d);
        auto q = hvdb::codec::Compare(ds.points, DracoDecode(s));
        D["position"][speed == 0 ? "draco_cl10" : "draco_cl7"].push_back(
            {{"qp", qp}, {"bpp", Bpp(s.size(), n)}, {"psnr", q.position_psnr}});
      }
    }
    // Colours and normals: bits = size(position + attribute) - size(position alone), both coders.
    hvdb::codec::EncodeOptions pos_only;
    pos_only.qp = qp_attr;
    pos_only.attributes = hvdb::codec::kPosition;
    const size_t ours_pos = OursEncode(ds.points, pos_only).size();
    DracoSettings dpos;
    dpos.qp = qp_attr;
    const size_t draco_pos = DracoEncode(ds.points, dpos).size();
    if (ds.color) {
      for (int qc : qcs) {
        hvdb::codec::EncodeOptions o = pos_only;
        o.attributes |= hvdb::codec::kColor;
        o.qc = qc;
        std::string s = OursEncode(ds.points, o);
        auto q = hvdb::codec::Compare(ds.points, OursDecode(s));
        D["color"]["ours_fixed"].push_back({{"qc", qc}, {"bpp", Bpp(s.size() - ours_pos, n)},
                                            {"psnr", q.y_psnr}, {"psnr_u", q.u_psnr},
                                            {"psnr_v", q.v_psnr}});
        DracoSettings d = dpos;
        d.color = true;
        d.qc = qc == 8 ? 0 : qc;
        std::string ds_ = DracoEncode(ds.points, d);
        auto qd = hvdb::codec::Compare(ds.points, DracoDecode(ds_));
        D["color"]["draco_cl10"].push_back({{"qc", qc}, {"bpp", Bpp(ds_.size() - draco_pos, n)},
                                            {"psnr", qd.y_psnr}, {"psnr_u", qd.u_psnr},
                                            {"psnr_v", qd.v_psnr}});
      }
    }
    if (ds.normal) {
      for (int qn : qns) {
        hvdb::codec::EncodeOptions o = pos_only;
        o.attributes |= hvdb::codec::kNormal;
        o.qn = qn;
        std::string s = OursEncode(ds.points, o);
        auto q = hvdb::codec::Compare(ds.points, OursDecode(s));
        D["normal"]["ours_fixed"].push_back(
            {{"qn", qn}, {"bpp", Bpp(s.size() - ours_pos, n)}, {"psnr", q.normal_psnr}});
        DracoSettings d = dpos;
        d.qn = qn;
        std::string ds_ = DracoEncode(ds.points, d);
        auto qd = hvdb::codec::Compare(ds.points, DracoDecode(ds_));
        D["normal"]["draco_cl10"].push_back(
            {{"qn", qn}, {"bpp", Bpp(ds_.size() - draco_pos, n)}, {"psnr", qd.normal_psnr}});
      }
    }
    json S;
    S["position_vs_draco_cl10"] = EqualPsnr(D["position"]["ours_fixed"], D["position"]["draco_cl10"]);
    if (ds.color) S["color_y_vs_draco_cl10"] = EqualPsnr(D["color"]["ours_fixed"], D["color"]["draco_cl10"]);
    if (ds.normal) S["normal_vs_draco_cl10"] = EqualPsnr(D["normal"]["ours_fixed"], D["normal"]["draco_cl10"]);
    std::vector<double> prog;
    for (size_t i = 0; i < D["position"]["ours_fixed"].size(); ++i) {
      prog.push_back(D["position"]["ours_progressive"][i]["bpp"].get<double>() /
                     D["position"]["ours_fixed"][i]["bpp"].get<double>());
    }
    S["progressive_over_fixed_position_bits"] = Median(prog);
    summary[ds.name] = S;
    std::fprintf(stderr, "  %s\n", S.dump().c_str());
  }

  // Lossless on a grid (what MPEG's G-PCC is compared on, bench/gpcc_compare.py): positions,
  // and positions + 8-bit colour, octree (version 2) against pair (version 1) geometry.
  json grid = json::object();
  for (const DataSet& ds : sets) {
    for (int qp : {10, 11}) {
      json G;
      for (bool color : {false, true}) {
        if (color && !ds.color) continue;
        hvdb::codec::EncodeOptions o;
        o.qp = qp;
        o.qc = 8;
        o.attributes = hvdb::codec::kPosition | (color ? hvdb::codec::kColor : 0u);
        json row;
        for (auto g : {hvdb::codec::EncodeOptions::Geometry::kOctree, hvdb::codec::EncodeOptions::Geometry::kPairs}) {
          o.geometry = g;
          row[g == hvdb::codec::EncodeOptions::Geometry::kOctree ? "octree_bpp" : "pairs_bpp"] =
              Bpp(OursEncode(ds.points, o).size(), ds.points.size());
        }
        row["octree_over_pairs"] = row["octree_bpp"].get<double>() / row["pairs_bpp"].get<double>();
        G[color ? "position_color" : "position"] = row;
      }
      grid[ds.name]["qp" + std::to_string(qp)] = G;
    }
  }
  std::fprintf(stderr, "lossless grid: %s\n", grid.dump().c_str());

  // Progressive prefixes of a full-attribute stream of the first Panoptic frame.
  hvdb::codec::EncodeOptions full;
  full.qp = 11;
  full.qc = 7;
  full.qn = 8;
  full.chunk = 2048;
  json prefixes = json::array();
  {
    hvdb::codec::EncodeOptions fixed = full;
    full.progressive = true;
    std::string sp = OursEncode(panoptic[0], full), sf = OursEncode(panoptic[0], fixed);
    summary["panoptic380"]["progressive_over_fixed_all_attributes"] =
        static_cast<double>(sp.size()) / static_cast<double>(sf.size());
    for (double frac : {0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0}) {
      size_t bytes = static_cast<size_t>(frac * static_cast<double>(sp.size()));
      std::vector<Point> dec;
      hvdb::codec::DecodeOptions o;
      o.max_bytes = bytes;
      if (!hvdb::codec::Decode(sp, &dec, o).ok()) continue;  // prefix shorter than the root
      auto q = hvdb::codec::Compare(panoptic[0], dec);
      prefixes.push_back({{"bytes", bytes}, {"fraction", frac}, {"points", dec.size()},
                          {"bpp", Bpp(bytes, panoptic[0].size())}, {"position_psnr", q.position_psnr},
                          {"y_psnr", q.y_psnr}});
    }
  }

  // Temporal against intra over the Panoptic sequence (same quantisation: same quality, since
  // the coding is lossless on the quantisation grid; only the bits differ).
  json temporal = json::array();
  std::vector<double> gains, gains_color;
  {
    hvdb::codec::EncodeOptions o;
    o.qp = 11;
    o.qc = 7;
    o.qn = 8;
    hvdb::codec::Reference ref;
    ref.points = OursDecode(OursEncode(panoptic[0], o));
    for (int f = 1; f < frames; ++f) {
      hvdb::codec::StreamStats si, st;
      std::string intra = OursEncode(panoptic[f], o, &si);
      std::string tem = OursEncode(panoptic[f], o, &st, &ref);
      std::vector<Point> dec = OursDecode(tem, &ref);
      if (dec != OursDecode(intra)) Die("temporal and intra decode differ");
      double g = 1.0 - static_cast<double>(tem.size()) / static_cast<double>(intra.size());
      double gc = 1.0 - static_cast<double>(st.bytes_by_attribute[1]) /
                            static_cast<double>(std::max<size_t>(1, si.bytes_by_attribute[1]));
      gains.push_back(g);
      gains_color.push_back(gc);
      const double np = static_cast<double>(panoptic[f].size());
      temporal.push_back({{"frame", 380 + f}, {"intra_bpp", 8.0 * intra.size() / np},
                          {"temporal_bpp", 8.0 * tem.size() / np}, {"saving", g},
                          {"color_saving", gc}});
      ref.points = std::move(dec);
    }
  }
  summary["temporal_saving_median"] = Median(gains);
  summary["temporal_color_saving_median"] = Median(gains_color);
  const json static_background = hvdb::bench::RunStaticBackground(scratch, quick);
  summary["static_background_position_saving_median"] = static_background["position_saving_median"];
  summary["static_background_position_color_saving_median"] =
      static_background["position_color_saving_median"];

  // Speed: all Panoptic frames as one point set.
  std::vector<Point> big;
  for (const auto& f : panoptic) big.insert(big.end(), f.begin(), f.end());
  json speed;
  {
    std::vector<double> enc, enc0, dec, denc, ddec;
    std::string s, s0, d;
    hvdb::codec::EncodeOptions best = full;
    best.chunk = hvdb::codec::EncodeOptions{}.chunk;  // the default: chunks worth a thread
    hvdb::codec::EncodeOptions fast = best;
    fast.effort = 0;
    for (int r = 0; r < reps; ++r) {
      auto t0 = Clock::now();
      s = OursEncode(big, best);
      enc.push_back(big.size() / Secs(t0) / 1e6);
      t0 = Clock::now();
      s0 = OursEncode(big, fast);
      enc0.push_back(big.size() / Secs(t0) / 1e6);
      t0 = Clock::now();
      auto back = OursDecode(s);
      dec.push_back(big.size() / Secs(t0) / 1e6);
      DracoSettings ds;
      ds.qp = 11;
      ds.color = true;
      ds.qn = 8;
      ds.speed = 3;
      t0 = Clock::now();
      d = DracoEncode(big, ds);
      denc.push_back(big.size() / Secs(t0) / 1e6);
      t0 = Clock::now();
      auto dback = DracoDecode(d);
      ddec.push_back(big.size() / Secs(t0) / 1e6);
    }
    // Lossless on an 11-bit grid, positions + colour: the octree and the pair geometry.
    std::vector<double> genc, gdec, penc, pdec;
    hvdb::codec::EncodeOptions g;
    g.qp = 11;
    g.qc = 8;
    g.attributes = hvdb::codec::kPosition | hvdb::codec::kColor;
    std::string gs, ps;
    for (int r = 0; r < reps; ++r) {
      auto t0 = Clock::now();
      gs = OursEncode(big, g);
      genc.push_back(big.size() / Secs(t0) / 1e6);
      t0 = Clock::now();
      auto back = OursDecode(gs);
      gdec.push_back(big.size() / Secs(t0) / 1e6);
      hvdb::codec::EncodeOptions p = g;
      p.geometry = hvdb::codec::EncodeOptions::Geometry::kPairs;
      t0 = Clock::now();
      ps = OursEncode(big, p);
      penc.push_back(big.size() / Secs(t0) / 1e6);
      t0 = Clock::now();
      back = OursDecode(ps);
      pdec.push_back(big.size() / Secs(t0) / 1e6);
    }
    speed["grid11_position_color"] = {
        {"octree_encode_mpts_s", Median(genc)}, {"octree_decode_mpts_s", Median(gdec)},
        {"octree_bpp", Bpp(gs.size(), big.size())}, {"pairs_encode_mpts_s", Median(penc)},
        {"pairs_decode_mpts_s", Median(pdec)}, {"pairs_bpp", Bpp(ps.size(), big.size())}};
    speed.update({{"points", big.size()}, {"ours_encode_mpts_s", Median(enc)},
             {"ours_effort0_encode_mpts_s", Median(enc0)}, {"ours_effort0_bpp", Bpp(s0.size(), big.size())},
             {"ours_decode_mpts_s", Median(dec)}, {"draco_cl7_encode_mpts_s", Median(denc)},
             {"draco_cl7_decode_mpts_s", Median(ddec)}, {"ours_bpp", Bpp(s.size(), big.size())},
             {"draco_cl7_bpp", Bpp(d.size(), big.size())},
             {"threads", std::thread::hardware_concurrency()}});
  }
  json j = {{"benchmark", "codec"}, {"quick", quick}, {"summary", summary}, {"rd", rd},
            {"lossless_grid", grid}, {"progressive_prefixes", prefixes}, {"temporal", temporal},
            {"static_background", static_background}, {"speed", speed}};
  std::ofstream(out) << j.dump(2) << "\n";
  std::printf("%s\n", json({{"summary", summary}, {"speed", speed}}).dump(2).c_str());
  if (plots) {
    std::string cmd = "/usr/bin/python3 " + std::string(HVDB_CODEC_PLOT) + " " + out;
    if (std::system(cmd.c_str()) != 0) Die("plotting failed: " + cmd);
  }
  return 0;
}
