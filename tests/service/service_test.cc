// The one executor (service/service.h): every kind of malformed request gets the same error code
// and the same message whichever way it comes: embedded (the executor called in this process, as
// `hvdb --data` and Python's hvdb.open call it), or through hvdb-server over TCP, over the Unix
// socket with the shared-memory ring, and over a browser's WebSocket. Each case is written once,
// as the executor's values; the wire requests are made from them by protocol/convert.h.
#include "service/service.h"

#include <gtest/gtest.h>
#include <google/protobuf/util/json_util.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <limits>
#include <random>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>

#include "client/client.h"
#include "formats/image_io.h"
#include "protocol/convert.h"
#include "protocol/render_convert.h"
#include "protocol/ws_codec.h"
#include "tests/server/server_process.h"

namespace hvdb::service {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace fs = std::filesystem;
using hvdb::testing::ServerProcess;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Points of two frames, the same in every data directory (seeded).
std::vector<Point> Points(uint32_t frame) {
  std::mt19937 rng(frame + 1);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Point> pts(500);
  for (auto& p : pts) {
    p.x = u(rng);
    p.y = u(rng);
    p.z = u(rng);
    p.frame = frame;
    p.cov = {1e-4f, 0, 0, 1e-4f, 0, 1e-4f};
    p.r = static_cast<uint8_t>(rng());
  }
  return pts;
}

void MakeData(const std::string& dir) {
  fs::create_directories(dir);
  auto db = Database::Open(dir, {});
  ASSERT_TRUE(db.ok()) << db.status().ToString();
  Service x(db->get(), dir);
  DatasetInfo info;
  info.name = "d";
  info.fps = 10;
  ASSERT_TRUE(x.CreateDataset(info).ok());
  ASSERT_TRUE(x.BulkLoad("d", 0, Points(0)).ok());
  ASSERT_TRUE(x.BulkLoad("d", 1, Points(1)).ok());
}

Region Box(double lo = -2, double hi = 2) {
  Window w;
  w.lo = {lo, lo, lo, 0};
  w.hi = {hi, hi, hi, 1};
  return w;
}

CameraInfo Cam() {
  CameraInfo c;
  c.id = 1;
  c.width = 64;
  c.height = 48;
  c.fx = c.fy = 50;
  c.cx = 32;
  c.cy = 24;
  c.world_from_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, -3, 0, 0, 0, 1};
  return c;
}

// One malformed request: what the executor does with it, and the same request for the wire.
struct Case {
  std::string name;
  std::function<Status(Service&)> embedded;
  std::function<wire::Request()> request;
  StatusCode code;
  wire::ErrorCode wire_code;
};

template <typename R>
Status StatusOf(const Result<R>& r) {
  return r.status();
}
Status StatusOf(const Status& s) { return s; }

std::vector<Case> Cases() {
  std::vector<Case> cases;
  auto add = [&](std::string name, StatusCode code, wire::ErrorCode wire_code, auto run,
                 auto to_wire) {
    cases.push_back({std::move(name), [run](Service& x) { return StatusOf(run(x)); },
                     [to_wire] {
                       wire::Request r;
                       to_wire(&r);
                       return r;
                     },
                     code, wire_code});
  };
  auto select = [&](std::string name, edit::SelectRequest req) {
    add(name, StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
        [req](Service& x) { return x.Select("d", req); },
        [req](wire::Request* r) {
          r->mutable_select()->set_dataset("d");
          wire::ToWire(req, r->mutable_select());
        });
  };
  auto graph_cut = [&](std::string name, edit::GraphCutRequest req) {
    add(name, StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
        [req](Service& x) { return x.GraphCut("d", req); },
        [req](wire::Request* r) {
          r->mutable_graph_cut()->set_dataset("d");
          wire::ToWire(req, r->mutable_graph_cut());
        });
  };
  auto query = [&](std::string name, Region region, QueryOptions o) {
    add(name, StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
        [region, o](Service& x) { return x.Query("d", region, o); },
        [region, o](wire::Request* r) {
          auto* q = r->mutable_query();
          q->set_dataset("d");
          wire::ToWire(region, q->mutable_region());
          wire::ToWire(o, q);
        });
  };

  {
    edit::SelectRequest s;
    s.region = Box();
    s.bit = 40;
    select("select: bit 40", s);
    s.bit = -1;
    select("select: bit -1", s);
    s.bit = 3;
    s.region = Box(1, -1);
    select("select: an empty window", s);
    Window w;
    w.lo = {kNaN, 0, 0, 0};
    w.hi = {1, 1, 1, 1};
    s.region = w;
    select("select: a NaN bound", s);
    s.region = Box();
    s.shape = edit::Lasso{Cam(), {{1, 1}, {5, 5}}};
    select("select: a lasso of two vertices", s);
    edit::Brush b;
    b.camera = Cam();
    b.radius = 0;
    s.shape = b;
    select("select: a brush of radius 0", s);
    edit::Lasso bad_cam{Cam(), {{1, 1}, {5, 5}, {1, 5}}};
    bad_cam.camera.fx = 0;
    s.shape = bad_cam;
    select("select: a camera without a focal length", s);
  }
  {
    edit::GraphCutRequest g;
    g.roi = Box();
    g.params.k = 0;
    graph_cut("graph cut: k 0", g);
    g.params.k = 65;
    graph_cut("graph cut: k 65", g);
    g.params.k = 8;
    g.params.intra_radius = -0.5;
    graph_cut("graph cut: a negative radius", g);
    g.params.intra_radius = 0.02;
    g.params.gmm_components = 0;
    graph_cut("graph cut: no colour components", g);
    g.params.gmm_components = 5;
    g.foreground_bit = g.background_bit = 2;
    graph_cut("graph cut: strokes on one bit", g);
    g.background_bit = 33;
    graph_cut("graph cut: background bit 33", g);
  }
  query("query: level 65", Box(), QueryOptions{.lod = 65});
  query("query: level -1", Box(), QueryOptions{.lod = -1});
  {
    Slice s;
    s.normal = {0, 0, 0, 0};
    query("query: a zero slice normal", s, {});
    s.normal = {0, 0, 0, 1};
    s.offset = kNaN;
    query("query: a NaN slice offset", s, {});
    s.offset = 0;
    s.thickness = -1;
    query("query: a negative thickness", s, {});
  }
  add("copy: bit 99", StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
      [](Service& x) { return x.Copy("d", {99, std::nullopt, "c", false}); },
      [](wire::Request* r) {
        r->mutable_copy()->set_dataset("d");
        wire::ToWire(edit::CopyRequest{99, std::nullopt, "c", false}, r->mutable_copy());
      });
  add("compact: first frame after the last", StatusCode::kInvalidArgument,
      wire::INVALID_PARAMETER, [](Service& x) { return x.Compact("d", 5, 2); },
      [](wire::Request* r) {
        r->mutable_compact()->set_dataset("d");
        r->mutable_compact()->set_first(5);
        r->mutable_compact()->set_last(2);
      });
  add("compact --photos: first frame after the last", StatusCode::kInvalidArgument,
      wire::INVALID_PARAMETER, [](Service& x) { return x.Compact("d", 9, 3, true); },
      [](wire::Request* r) {
        r->mutable_compact()->set_dataset("d");
        r->mutable_compact()->set_first(9);
        r->mutable_compact()->set_last(3);
        r->mutable_compact()->set_photos(true);
      });
  add("paste: a clipboard that does not exist", StatusCode::kNotFound, wire::NOT_FOUND,
      [](Service& x) { return x.Paste("d", {"nothing-here", {}}); },
      [](wire::Request* r) {
        r->mutable_paste()->set_dataset("d");
        wire::ToWire(edit::PasteRequest{"nothing-here", {}}, r->mutable_paste());
      });
  {
    edit::CompositeRequest c{Points(0), 0, 0, {}};
    add("composite: zero frames", StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
        [c](Service& x) { return x.Composite("d", c); },
        [c](wire::Request* r) {
          r->mutable_composite()->set_dataset("d");
          wire::ToWire(c, r->mutable_composite());
        });
    edit::CompositeRequest t{Points(0), 0, 3, {{0, 0, 0}}};
    add("composite: a trajectory shorter than the frames", StatusCode::kInvalidArgument,
        wire::INVALID_PARAMETER, [t](Service& x) { return x.Composite("d", t); },
        [t](wire::Request* r) {
          r->mutable_composite()->set_dataset("d");
          wire::ToWire(t, r->mutable_composite());
        });
  }
  {
    auto import = [&](std::string name, StatusCode code, wire::ErrorCode wire_code,
                      media::ImportRequest req, std::string ds = "d") {
      add(name, code, wire_code, [req, ds](Service& x) { return x.ImportMedia(ds, req); },
          [req, ds](wire::Request* r) {
            r->mutable_import_media()->set_dataset(ds);
            wire::ToWire(req, r->mutable_import_media());
          });
    };
    media::ImportRequest m;
    m.data = "\x89PNG\r\n\x1a\n but not a picture";
    m.format = "png";
    m.kind = media::Kind::kImage;
    import("import_media: a corrupt image", StatusCode::kInvalidArgument,
           wire::INVALID_PARAMETER, m);
    media::ImportRequest b = m;
    b.kind = media::Kind::kVideo;
    import("import_media: a corrupt video", StatusCode::kInvalidArgument,
           wire::INVALID_PARAMETER, b);
    b.kind = media::Kind::kMesh;
    b.format = "obj";
    b.data = "v 0 0 0\nf 1 2 3\n";
    import("import_media: a corrupt mesh", StatusCode::kInvalidArgument,
           wire::INVALID_PARAMETER, b);
    b = m;
    b.label_bit = 40;
    import("import_media: label bit 40", StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
           b);
    b = m;
    b.first_frame = 3;
    b.last_frame = 1;
    import("import_media: frames backwards", StatusCode::kInvalidArgument,
           wire::INVALID_PARAMETER, b);
    b = m;
    b.place.scale = kNaN;
    import("import_media: scale NaN", StatusCode::kInvalidArgument, wire::INVALID_PARAMETER, b);
    b = m;
    b.data.clear();
    import("import_media: no bytes", StatusCode::kInvalidArgument, wire::INVALID_PARAMETER, b);
    import("import_media: a dataset that does not exist", StatusCode::kNotFound,
           wire::UNKNOWN_DATASET, m, "nope");
  }
  add("describe: a dataset that does not exist", StatusCode::kNotFound, wire::UNKNOWN_DATASET,
      [](Service& x) { return x.Describe("nope"); },
      [](wire::Request* r) { r->mutable_describe()->set_dataset("nope"); });
  {
    edit::SelectRequest s;
    s.region = Box();
    add("select: in a dataset that does not exist", StatusCode::kNotFound,
        wire::UNKNOWN_DATASET, [s](Service& x) { return x.Select("nope", s); },
        [s](wire::Request* r) {
          r->mutable_select()->set_dataset("nope");
          wire::ToWire(s, r->mutable_select());
        });
  }
  {
    Transaction t;
    std::vector<Point> bad = Points(0);
    bad[3].y = static_cast<float>(kNaN);
    t.Insert(bad);
    add("edit: a point with a NaN coordinate", StatusCode::kInvalidArgument,
        wire::INVALID_PARAMETER, [t](Service& x) { return x.Commit("d", t); },
        [t](wire::Request* r) {
          r->mutable_edit()->set_dataset("d");
          wire::ToWire(t, r->mutable_edit());
        });
  }
  {
    DatasetInfo info;
    info.name = "slow";
    info.fps = 0;
    add("create: 0 frames a second", StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
        [info](Service& x) { return x.CreateDataset(info); },
        [info](wire::Request* r) { wire::ToWire(info, r->mutable_create()); });
    info.name = "d";
    info.fps = 10;
    add("create: a name taken", StatusCode::kAlreadyExists, wire::ALREADY_EXISTS,
        [info](Service& x) { return x.CreateDataset(info); },
        [info](wire::Request* r) { wire::ToWire(info, r->mutable_create()); });
  }
  {
    Photo p{Cam(), "not an image", {}};
    p.camera.fx = 0;
    add("put photo: a camera without a focal length", StatusCode::kInvalidArgument,
        wire::INVALID_PARAMETER, [p](Service& x) { return x.PutPhoto("d", 0, p); },
        [p](wire::Request* r) {
          r->mutable_put_photo()->set_dataset("d");
          wire::ToWire(p, r->mutable_put_photo());
        });
    Photo q{Cam(), "not an image", {}};
    add("put photo: an image that does not decode", StatusCode::kInvalidArgument,
        wire::INVALID_PARAMETER, [q](Service& x) { return x.PutPhoto("d", 0, q); },
        [q](wire::Request* r) {
          r->mutable_put_photo()->set_dataset("d");
          wire::ToWire(q, r->mutable_put_photo());
        });
  }
  {
    // Render: shadows and video export (render/job.cc checks them when the job is made).
    auto render = [&](std::string name, wire::Render req) {
      req.set_dataset("d");
      add(name, StatusCode::kInvalidArgument, wire::INVALID_PARAMETER,
          [req](Service& x) -> Status {
            // As hvdb-server decodes it (protocol/render_convert.h), then the executor's job.
            Result<render::RenderRequest> r = wire::FromWire(req);
            if (!r.ok()) return r.status();
            return x.Render(*r).status();
          },
          [req](wire::Request* r) { *r->mutable_render() = req; });
    };
    wire::Render base;
    wire::ToWire(Box(), base.mutable_region());
    wire::ToWire(Cam(), base.mutable_view()->mutable_camera());
    wire::Render shadow = base;
    for (double v : {0.0, -3.0, 0.0}) shadow.add_shadow_light(v);
    shadow.set_shadow_casters(32);
    render("render: shadow casters bit 32", shadow);
    shadow.set_shadow_casters(1);
    shadow.set_shadow_strength(1.5f);
    render("render: shadow strength 1.5", shadow);
    wire::Render video = base;
    video.set_format(wire::IMAGE_MP4);
    render("render: a video without a path", video);
    video.clear_view();
    wire::ToWire(Cam(), video.add_path()->mutable_camera());
    video.set_width(63);
    video.set_height(48);
    render("render: a video of odd width", video);
    wire::Render deep = base;
    deep.set_lod(65);  // storage's rule, as for a query (Dataset::CheckLod)
    render("render: level 65", deep);
  }
  return cases;
}

// A synchronous WebSocket client of hvdb-server --http: requests go as binary protobuf
// messages, responses come back as JSON text (docs/PROTOCOL.md, "HTTP and WebSocket").
class Ws {
 public:
  explicit Ws(uint16_t port) {
    ws_.next_layer().connect({asio::ip::address_v4::loopback(), port});
    ws_.handshake("127.0.0.1:" + std::to_string(port), "/ws");
    ws_.text(true);
    ws_.write(asio::buffer(std::string(R"({"protocol_version": 2, "client_name": "table"})")));
    beast::flat_buffer b;
    ws_.read(b);  // the HelloReply
  }
  wire::Response Call(const wire::Request& req) {
    ws_.binary(true);
    ws_.write(asio::buffer(req.SerializeAsString()));
    beast::flat_buffer b;
    ws_.read(b);
    wire::Response r;
    auto st = google::protobuf::util::JsonStringToMessage(beast::buffers_to_string(b.data()), &r);
    EXPECT_TRUE(st.ok()) << st.ToString();
    return r;
  }

 private:
  asio::io_context io_;
  beast::websocket::stream<asio::ip::tcp::socket> ws_{io_};
};

class ServiceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() /
            ("hvdb-service-" + std::to_string(::getpid()) + "-" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root_);
    MakeData(root_ / "embedded");
    MakeData(root_ / "served");
  }
  void TearDown() override { fs::remove_all(root_); }
  fs::path root_;
};

TEST_F(ServiceTest, MalformedRequestsGetOneAnswerOnEveryTransport) {
  const std::string sock = (root_ / "hvdb.sock").string();
  ServerProcess server((root_ / "served").string(),
                       {"--listen", "unix:" + sock, "--http", "127.0.0.1:0"});
  ASSERT_TRUE(server.running());

  client::Options tcp;
  tcp.port = server.port();
  tcp.prefer_local = false;  // stay on TCP
  auto over_tcp = client::Connection::Connect(tcp);
  ASSERT_TRUE(over_tcp.ok()) << over_tcp.status().ToString();
  EXPECT_EQ((*over_tcp)->transport().rfind("tcp", 0), 0u) << (*over_tcp)->transport();
  client::Options unix_ring;
  unix_ring.unix_path = sock;
  auto over_unix = client::Connection::Connect(unix_ring);
  ASSERT_TRUE(over_unix.ok()) << over_unix.status().ToString();
  EXPECT_NE((*over_unix)->transport().find("shared memory"), std::string::npos)
      << (*over_unix)->transport();
  Ws ws(server.http_port());

  auto db = Database::Open((root_ / "embedded").string(), {});
  ASSERT_TRUE(db.ok());
  Service embedded(db->get(), (root_ / "embedded").string());

  const std::vector<Case> cases = Cases();
  ASSERT_GE(cases.size(), 25u);
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Status want = c.embedded(embedded);
    ASSERT_FALSE(want.ok()) << "the embedded executor accepted it";
    EXPECT_EQ(want.code(), c.code) << want.ToString();
    auto remote = [&](client::Connection& conn) -> wire::Response {
      wire::Request req = c.request();
      auto id = conn.Send(&req);
      EXPECT_TRUE(id.ok()) << id.status().ToString();
      auto r = conn.Receive(*id);
      EXPECT_TRUE(r.ok()) << r.status().ToString();
      return r.ok() ? *r : wire::Response();
    };
    const std::pair<const char*, wire::Response> answers[] = {
        {"tcp", remote(**over_tcp)},
        {"unix + ring", remote(**over_unix)},
        {"websocket", ws.Call(c.request())}};
    for (const auto& [transport, r] : answers) {
      SCOPED_TRACE(transport);
      ASSERT_TRUE(r.has_error());
      EXPECT_EQ(r.error().code(), c.wire_code) << wire::ErrorCode_Name(r.error().code());
      const Status got = wire::FromWire(r.error());
      EXPECT_EQ(got.code(), want.code());
      EXPECT_EQ(got.message(), want.message());
    }
  }
  // Nothing of it reached the data: both directories still hold the same two frames.
  auto served = client::Connection::Connect(tcp);
  ASSERT_TRUE(served.ok());
  auto st = (*served)->Stats("d");
  ASSERT_TRUE(st.ok());
  auto mine = embedded.Stats("d");
  ASSERT_TRUE(mine.ok());
  EXPECT_EQ(st->dataset().points(), mine->stats.points);
  EXPECT_EQ(st->dataset().points(), 1000u);
  EXPECT_EQ(st->last_lsn(), mine->last_lsn);
}

// The same good request gives the same values embedded and served (the typed statistics
// included, which replaced a JSON string inside the reply).
TEST_F(ServiceTest, AGoodRequestGetsTheSameValuesEverywhere) {
  ServerProcess server((root_ / "served").string());
  ASSERT_TRUE(server.running());
  client::Options tcp;
  tcp.port = server.port();
  auto conn = client::Connection::Connect(tcp);
  ASSERT_TRUE(conn.ok());
  auto db = Database::Open((root_ / "embedded").string(), {});
  ASSERT_TRUE(db.ok());
  Service embedded(db->get(), (root_ / "embedded").string());

  edit::SelectRequest s;
  s.region = Box(-0.5, 0.5);
  s.bit = 4;
  auto mine = embedded.Select("d", s);
  ASSERT_TRUE(mine.ok()) << mine.status().ToString();
  wire::SelectRequest q;
  q.set_dataset("d");
  wire::ToWire(s, &q);
  auto theirs = (*conn)->Select(q);
  ASSERT_TRUE(theirs.ok()) << theirs.status().ToString();
  auto back = wire::FromWire(*theirs);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  const edit::SelectResult& t = *back;
  EXPECT_GT(mine->selected, 0u);
  EXPECT_EQ(t.matched, mine->matched);
  EXPECT_EQ(t.selected, mine->selected);
  EXPECT_EQ(t.lsn, mine->lsn);

  // Into the cold tier, both ways.
  auto compacted = embedded.Compact("d", 0, 1);
  ASSERT_TRUE(compacted.ok()) << compacted.status().ToString();
  auto served = (*conn)->Compact("d", 0, 1);
  ASSERT_TRUE(served.ok()) << served.status().ToString();
  EXPECT_EQ(compacted->frames, 2u);
  EXPECT_EQ(served->frames, compacted->frames);
  EXPECT_EQ(served->points, compacted->points);
  // Photos into the video tier, both ways: two frames of one camera become one video, and the
  // points are left alone.
  formats::Image gradient;
  gradient.width = 64;
  gradient.height = 48;
  gradient.rgba.resize(gradient.pixels() * 4, 1.f);
  for (size_t i = 0; i < gradient.pixels(); ++i) {
    gradient.rgba[4 * i] = float(i % 64) / 63.f;
    gradient.rgba[4 * i + 1] = float(i / 64) / 47.f;
  }
  auto png = formats::EncodePng(gradient);
  ASSERT_TRUE(png.ok());
  for (uint32_t f : {0u, 1u}) {
    ASSERT_TRUE(embedded.PutPhoto("d", f, Photo{Cam(), *png, {}}).ok());
    ASSERT_TRUE((*conn)->PutPhoto("d", f, Photo{Cam(), *png, {}}).ok());
  }
  auto photos_mine = embedded.Compact("d", 0, 1, true);
  ASSERT_TRUE(photos_mine.ok()) << photos_mine.status().ToString();
  auto photos_served = (*conn)->Compact("d", 0, 1, true);
  ASSERT_TRUE(photos_served.ok()) << photos_served.status().ToString();
  EXPECT_EQ(photos_mine->photo_runs, 1u);
  EXPECT_EQ(photos_mine->photo_pictures, 2u);
  EXPECT_EQ(photos_served->photo_runs, photos_mine->photo_runs);
  EXPECT_EQ(photos_served->photo_pictures, photos_mine->photo_pictures);
  EXPECT_EQ(photos_served->photo_bytes_before, photos_mine->photo_bytes_before);
  EXPECT_GE(photos_served->photo_min_psnr, 40.0);
  EXPECT_EQ(photos_served->frames, 0u);

  auto st = (*conn)->Stats("d");
  ASSERT_TRUE(st.ok());
  auto report = embedded.Stats("d");
  ASSERT_TRUE(report.ok());
  const DatasetStats a = wire::FromWire(st->dataset()), b = report->stats;
  EXPECT_EQ(a.points, b.points);
  EXPECT_EQ(a.frames_with_data, b.frames_with_data);
  EXPECT_EQ(a.tombstones, b.tombstones);
  EXPECT_EQ(a.cold_frames, 2u);
  EXPECT_EQ(a.cold_frames, b.cold_frames);
  EXPECT_EQ(a.cold_points, b.cold_points);
  EXPECT_EQ(st->last_lsn(), report->last_lsn);
}

}  // namespace
}  // namespace hvdb::service
