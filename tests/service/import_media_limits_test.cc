// import-media against hostile files (docs/PROTOCOL.md, "Limits"): each file of a probe of the
// server as a read-write client, and its siblings, through the executor embedded (as `hvdb
// --data` and Python run it) and through a real hvdb-server. None may crash the process, read a
// file other than its own bytes, or take more memory than the job budget; each gets an error
// that says what is wrong (naming the limit where one was hit), and nothing is written.
#include <sys/stat.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "client/client.h"
#include "protocol/convert.h"
#include "service/service.h"
#include "tests/server/server_process.h"

namespace hvdb::service {
namespace {

namespace fs = std::filesystem;
using hvdb::testing::ServerProcess;

constexpr uint64_t kBudgetMiB = 64;

struct BadFile {
  std::string name;
  media::ImportRequest req;
  std::vector<std::string> expect;  // every one of these is in the error
};

media::ImportRequest File(std::string data, std::string format,
                          media::Kind kind = media::Kind::kAuto) {
  media::ImportRequest r;
  r.data = std::move(data);
  r.format = std::move(format);
  r.kind = kind;
  return r;
}

std::string Ply(const std::string& face) {
  return "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
         "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
         "0 0 0\n1 0 0\n0 1 0\n" + face + "\n";
}

// A one-triangle glTF whose buffer is `uri`; `extra` goes into the top-level object.
std::string Gltf(const std::string& uri, const std::string& extra = "") {
  return R"({"asset":{"version":"2.0"},"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],)"
         R"("meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],)"
         R"("buffers":[{"uri":")" + uri + R"(","byteLength":36}],)"
         R"("bufferViews":[{"buffer":0,"byteLength":36}],)"
         R"("accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",)"
         R"("min":[0,0,0],"max":[1,1,0]}])" + extra + "}";
}

constexpr char kTriangle[] =  // three float vec3, base64
    "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA";

std::string Le32(uint32_t v) {
  return std::string{static_cast<char>(v), static_cast<char>(v >> 8), static_cast<char>(v >> 16),
                     static_cast<char>(v >> 24)};
}

// A JPEG of w x h whose SOF then says `dw` x `dh`.
std::string JpegSaying(uint16_t dw, uint16_t dh) {
  std::vector<uint8_t> buf;
  EXPECT_TRUE(cv::imencode(".jpg", cv::Mat(16, 16, CV_8UC3, cv::Scalar(10, 200, 30)), buf));
  std::string s(buf.begin(), buf.end());
  const size_t sof = s.find("\xff\xc0");
  EXPECT_NE(sof, std::string::npos);
  s[sof + 5] = static_cast<char>(dh >> 8);
  s[sof + 6] = static_cast<char>(dh);
  s[sof + 7] = static_cast<char>(dw >> 8);
  s[sof + 8] = static_cast<char>(dw);
  return s;
}

std::string Jpeg(int w, int h, cv::Scalar colour) {
  std::vector<uint8_t> buf;
  EXPECT_TRUE(cv::imencode(".jpg", cv::Mat(h, w, CV_8UC3, colour), buf));
  return std::string(buf.begin(), buf.end());
}

// The files, in `dir` (where a FIFO is made for one of them).
std::vector<BadFile> BadFiles(const std::string& dir) {
  std::vector<BadFile> v;
  const std::string outside = "outside the bytes sent";
  v.push_back({"ply face past the vertices", File(Ply("3 0 1 200000000"), "ply"), {"the mesh"}});
  v.push_back({"ply negative index", File(Ply("3 0 1 -5"), "ply"), {"the mesh"}});
  {
    // 100 000 nodes, each the child of the one before.
    std::string nodes;
    for (int i = 0; i < 100000; ++i) {
      nodes += i + 1 < 100000 ? R"({"children":[)" + std::to_string(i + 1) + "]}," : R"({"mesh":0})";
    }
    std::string g = Gltf(kTriangle);
    g.replace(g.find(R"("nodes":[{"mesh":0}])"), 20, R"("nodes":[)" + nodes + "]");
    v.push_back({"glTF of 100 000 nested nodes", File(g, "gltf"), {"nests its nodes", "128"}});
  }
  v.push_back({"glTF with 2 million nested arrays",
               File(Gltf(kTriangle, R"(,"extras":)" + std::string(2000000, '[') +
                                        std::string(2000000, ']')),
                    "gltf"),
               {"nests its JSON", "64"}});
  for (const std::string uri : {"/etc/passwd", "hvdb.sock", "../../../../etc/passwd",
                                "/dev/zero", "file:///etc/passwd", "file:../x.bin"}) {
    v.push_back({"glTF buffer at " + uri, File(Gltf(uri), "gltf"), {outside, uri}});
  }
  const std::string fifo = dir + "/fifo";
  ::mkfifo(fifo.c_str(), 0600);
  v.push_back({"glTF buffer at a FIFO", File(Gltf(fifo), "gltf"), {outside, fifo}});
  v.push_back({"glTF image at a path",
               File(Gltf(kTriangle, R"(,"images":[{"uri":"/etc/hostname"}])"), "gltf"),
               {outside, "/etc/hostname"}});
  v.push_back({"OBJ mtllib /etc/passwd",
               File("mtllib /etc/passwd\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj"),
               {outside, "/etc/passwd"}});
  {
    // 648 bytes whose JSON chunk says 4 GiB.
    std::string json = Gltf(kTriangle);
    json.resize(628, ' ');
    const std::string glb = "glTF" + Le32(2) + Le32(648) + Le32(0xFFFFFFF0u) + "JSON" + json;
    v.push_back({"GLB declaring a 4 GiB chunk", File(glb, "glb"), {"chunk of 4294967280 bytes"}});
  }
  {
    const std::string g = Gltf(kTriangle, R"(,"extensionsUsed":[])");
    std::string cyc = g;
    cyc.replace(cyc.find(R"("nodes":[{"mesh":0}])"), 20,
                R"("nodes":[{"mesh":0,"children":[1]},{"children":[0]}])");
    v.push_back({"glTF nodes in a cycle", File(cyc, "gltf"), {"the mesh"}});
    std::string big = g;
    big.replace(big.find(R"("count":3)"), 9, R"("count":1000000000)");
    v.push_back({"glTF accessor past its view", File(big, "gltf"), {"outside its buffer view"}});
  }
  v.push_back({"JPEG saying 20000 x 20000", File(JpegSaying(20000, 20000), "jpg"),
               {"20000x20000", "over the limit"}});
  v.push_back({"JPEG saying 16000 x 16000", File(JpegSaying(16000, 16000), "jpg"),
               {"16000x16000", "more than its"}});
  {
    // A PNG whose IHDR says 16000 x 16000 over 32 x 32 pixels of data.
    std::vector<uint8_t> buf;
    EXPECT_TRUE(cv::imencode(".png", cv::Mat(32, 32, CV_8UC1, cv::Scalar(7)), buf));
    std::string png(buf.begin(), buf.end());
    const std::string side("\x00\x00\x3e\x80", 4);  // 16000, big-endian
    png.replace(16, 4, side);
    png.replace(20, 4, side);
    v.push_back({"PNG saying 16000 x 16000", File(png, "png"), {"16000x16000"}});
  }
  v.push_back({"a format not read here", File("anything", "fbx", media::Kind::kMesh),
               {"OBJ, PLY, STL, OFF, glTF or GLB"}});
  {
    // An MJPEG stream of one 16 x 16 frame, then 80 of 512 x 512, at full size over 80 frames:
    // the first frame's size says 20 k points, the rest 21 M.
    std::string mjpeg = Jpeg(16, 16, {0, 0, 255});
    const std::string big = Jpeg(512, 512, {0, 255, 0});
    for (int i = 0; i < 80; ++i) mjpeg += big;
    media::ImportRequest r = File(mjpeg, "mjpeg", media::Kind::kVideo);
    r.texels = 4096;
    r.first_frame = 0;
    r.last_frame = 79;
    v.push_back({"MJPEG that grows after its first frame", r, {"import_media"}});
  }
  return v;
}

void Check(const BadFile& b, const Status& st) {
  SCOPED_TRACE(b.name);
  ASSERT_FALSE(st.ok());
  for (const std::string& e : b.expect) {
    EXPECT_NE(st.message().find(e), std::string::npos) << st.ToString();
  }
}

class ImportMediaLimitsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    data_ = dir_ + "/data";
    fs::create_directories(data_);
    auto db = Database::Open(data_, {});
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    Service x(db->get(), data_);
    DatasetInfo info;
    info.name = "d";
    info.fps = 10;
    info.frame_count = 80;
    ASSERT_TRUE(x.CreateDataset(info).ok());
    Point p;
    ASSERT_TRUE(x.BulkLoad("d", 0, {p}).ok());
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string dir_ = fs::temp_directory_path() / ("hvdb_import_limits_" + std::to_string(::getpid()));
  std::string data_;
};

TEST_F(ImportMediaLimitsTest, EmbeddedEveryFileIsRefusedAndNothingIsWritten) {
  auto db = Database::Open(data_, {});
  ASSERT_TRUE(db.ok());
  JobConfig jobs;
  jobs.memory_budget = kBudgetMiB << 20;
  Service x(db->get(), data_, nullptr, nullptr, jobs);
  const uint64_t lsn = (*x.Describe("d")).last_lsn;
  for (const BadFile& b : BadFiles(dir_)) {
    const auto t0 = std::chrono::steady_clock::now();
    Check(b, x.ImportMedia("d", b.req).status());
    // Refused from what the file declares, not after decoding it.
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5)) << b.name;
  }
  EXPECT_EQ((*x.Describe("d")).last_lsn, lsn);
}

TEST_F(ImportMediaLimitsTest, ServedEveryFileIsRefusedTheServerKeepsServingWithinItsBudget) {
  ServerProcess server(data_, {"--memory-budget", std::to_string(kBudgetMiB)});
  ASSERT_TRUE(server.running());
  client::Options o;
  o.port = server.port();
  o.prefer_local = false;
  o.request_timeout = std::chrono::milliseconds(60000);
  auto c = client::Connection::Connect(o);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  auto send = [&](const media::ImportRequest& r) {
    wire::ImportMediaRequest q;
    ToWire(r, &q);
    q.set_dataset("d");
    return (*c)->ImportMedia(q);
  };
  // The decoders' libraries loaded once (their code is resident memory too), with a file of
  // each kind that imports, then undone.
  const uint64_t lsn0 = (*(*c)->Describe("d")).last_lsn;
  media::ImportRequest warm = File(Jpeg(8, 8, {1, 2, 3}), "jpg");
  warm.first_frame = warm.last_frame = 0;
  ASSERT_TRUE(send(warm).ok());
  media::ImportRequest mesh = File(Gltf(kTriangle), "gltf");
  mesh.first_frame = mesh.last_frame = 0;
  mesh.spacing = 0.1;
  ASSERT_TRUE(send(mesh).ok()) << send(mesh).status().ToString();
  // A video: FFmpeg is loaded by the first one (formats/libav.h), not at the server's start.
  media::ImportRequest video =
      File(Jpeg(16, 16, {0, 0, 255}) + Jpeg(16, 16, {0, 255, 0}), "mjpeg", media::Kind::kVideo);
  video.first_frame = video.last_frame = 0;
  ASSERT_TRUE(send(video).ok()) << send(video).status().ToString();
  const uint64_t lsn = (*(*c)->Describe("d")).last_lsn;
  ASSERT_GT(lsn, lsn0);
  const long before = server.RssKib();
  long peak = before;
  for (const BadFile& b : BadFiles(dir_)) {
    Check(b, send(b.req).status());
    peak = std::max(peak, server.RssKib());
    if (std::getenv("HVDB_TEST_VERBOSE") != nullptr) {  // each file's growth
      std::ifstream st("/proc/" + std::to_string(server.pid()) + "/status");
      std::string k;
      long v = 0;
      while (st >> k) if (k == "VmHWM:") st >> v;
      std::fprintf(stderr, "%s: rss %ld hwm %ld\n", b.name.c_str(), server.RssKib() - before, v - before);
    }
    ASSERT_TRUE((*c)->ListDatasets().ok()) << "the server stopped serving after " << b.name;
  }
  EXPECT_EQ((*(*c)->Describe("d")).last_lsn, lsn);
  // Sampled after each request: what a request held while it ran is gone by then, so the
  // process's high-water mark is the bound that matters.
  std::ifstream status("/proc/" + std::to_string(server.pid()) + "/status");
  std::string key;
  long hwm = 0;
  while (status >> key) {
    if (key == "VmHWM:") status >> hwm;
  }
  // The jobs' budget, plus what the requests themselves are held as outside it (bounded by
  // --max-frame-bytes: the largest here, 4 MB, is the frame read, the parsed message and the
  // executor's copy) and the allocator's slack.
  const long bound = static_cast<long>(kBudgetMiB + 16) * 1024;
  EXPECT_LT(peak - before, bound);
  EXPECT_LT(hwm - before, bound) << "peak RSS " << hwm << " KiB";
}

// A picture that is what it says (16000 x 16000, 250 KB of deflate) is a valid file: it decodes
// row by row into its texel grid, in the memory of the grid.
TEST_F(ImportMediaLimitsTest, AValidPictureOfAQuarterGigapixelDecodesInTheMemoryOfItsTexels) {
  std::vector<uint8_t> buf;
  ASSERT_TRUE(cv::imencode(".png", cv::Mat(16000, 16000, CV_8UC1, cv::Scalar(90)), buf,
                           {cv::IMWRITE_PNG_COMPRESSION, 9}));
  auto db = Database::Open(data_, {});
  ASSERT_TRUE(db.ok());
  JobConfig jobs;
  jobs.memory_budget = 16u << 20;
  Service x(db->get(), data_, nullptr, nullptr, jobs);
  media::ImportRequest r = File(std::string(buf.begin(), buf.end()), "png");
  r.texels = 64;
  r.first_frame = r.last_frame = 0;
  auto ci = x.ImportMedia("d", r);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  EXPECT_EQ(ci->inserted, 64u * 64);
  // At 4096 texels the grid alone is 64 MiB: over this budget, and said so.
  r.texels = 4096;
  auto over = x.ImportMedia("d", r);
  ASSERT_FALSE(over.ok());
  EXPECT_TRUE(over.status().code() == StatusCode::kLimitExceeded) << over.status().ToString();
  EXPECT_NE(over.status().message().find("--memory-budget"), std::string::npos);
}

TEST_F(ImportMediaLimitsTest, AJobPastItsTimeIsStoppedNamingTheLimit) {
  auto db = Database::Open(data_, {});
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("d");
  ASSERT_TRUE(ds.ok());
  JobLimits late;
  late.max_seconds = 1;
  late.start = std::chrono::steady_clock::now() - std::chrono::seconds(2);
  auto r = media::Import(**ds, File(Jpeg(64, 64, {9, 9, 9}), "jpg"), late);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kLimitExceeded);
  EXPECT_NE(r.status().message().find("--max-job-seconds"), std::string::npos) << r.status().ToString();
}

}  // namespace
}  // namespace hvdb::service
