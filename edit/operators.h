// Editing operators (thesis chapter 9): selections stored as label bits, 4D graph-cut object
// selection, cut / copy / paste through named clipboards, compositing. Each change is one edit
// transaction of the dataset, so it is atomic, durable and undoable (Dataset::Revert; redo is
// the revert of the revert).
//
// The operators run next to the data: in hvdb-server (requests of docs/PROTOCOL.md) or embedded.
#ifndef HVDB_EDIT_OPERATORS_H_
#define HVDB_EDIT_OPERATORS_H_

#include <array>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "edit/graph_cut.h"
#include "storage/database.h"
#include "storage/gaussian_column.h"

namespace hvdb::edit {

// How a new selection combines with the points already carrying the label bit.
enum class SelectMode { kReplace, kAdd, kSubtract, kIntersect };

// A screen-space marquee or lasso (polygon in pixels), extruded through the camera into the
// viewed region (9.3.1). Positions are those the viewer sees: projected ones for a slice.
struct Lasso {
  CameraInfo camera;
  std::vector<std::array<double, 2>> polygon;  // >= 3 vertices
};

// The 3D paintbrush: a sphere of `radius` metres around the front surface under the pixel
// (u, v); the surface depth is the nearest or the median depth of the points whose projection
// lies within `pixel_radius` of (u, v).
struct Brush {
  CameraInfo camera;
  double u = 0, v = 0, pixel_radius = 5;
  double radius = 0.02;
  enum class Depth { kNearest, kMedian } depth = Depth::kMedian;
};

struct SelectRequest {
  Region region;  // what is viewed; the selection never reaches outside it
  std::variant<std::monostate, Lasso, Brush> shape;  // monostate: the whole region
  int bit = 0;                                       // label bit 0..31 that holds the selection
  SelectMode mode = SelectMode::kReplace;
  // Fill SelectResult::flips with the changes in the frames `region` covers (what a client
  // showing the region redraws; a replace's clears in other frames are not listed).
  bool return_flips = false;
};

// The points of one frame whose selection bit a Select set or cleared, ids ascending: what a
// client showing them needs to redraw their labels without querying the frame again.
struct LabelFlips {
  uint32_t frame = 0;
  bool set = false;
  std::vector<uint64_t> ids;
};

struct SelectResult {
  uint64_t matched = 0;   // points the shape covered
  uint64_t selected = 0;  // points carrying the bit afterwards
  uint64_t lsn = 0;       // 0 when nothing changed
  std::optional<std::array<double, 3>> brush_center;
  std::vector<LabelFlips> flips;  // with return_flips: cleared ones first, then set ones
};

Result<SelectResult> Select(Dataset& ds, const SelectRequest& req);

struct GraphCutRequest {
  Region roi;  // the region of interest (green paint)
  int foreground_bit = 1, background_bit = 2;  // the strokes (red and blue paint)
  int out_bit = 0;                             // receives the selection inside the ROI
  GraphCutParams params;
};

struct GraphCutReply {
  uint64_t roi_points = 0, selected = 0, lsn = 0;
  GraphCutResult cut;  // energy, edge counts and timings (selected[] cleared; cut.warm: a re-cut)
  double load_ms = 0, commit_ms = 0;
  bool labels_only = false;  // a re-cut that read only the labelled points (GraphCutCache)
};

// The last cut's graph and flow (graph_cut.h's GraphCut), kept between requests: a cut over
// the same points (the same region of the same data; labels may differ, as strokes and the
// last selection change them) is a re-cut that starts from the last flow. One entry, for
// regions of at most max_points points (the graph holds ~250 bytes a point); cuts through it
// are serialised.
//
// The cache watches the dataset of its graph (Dataset::Watch): while every change since the
// graph was read only flipped labels (ChangeEvent::labels_only), a re-cut of the same region
// with the same parameters reads only the points carrying a stroke bit (a label-masked query,
// which skips buckets without them) instead of the whole region, and knows which points carry
// the output bit from its own last commit unless a change since flipped that bit.
class GraphCutCache {
 public:
  explicit GraphCutCache(size_t max_points = size_t{2} << 20) : max_points_(max_points) {}

 private:
  friend Result<GraphCutReply> GraphCutSelect(Dataset&, const GraphCutRequest&, GraphCutCache*);
  // What the watch has seen of the graph's dataset (ev_mu_: the watch's callback takes only
  // this lock, never mu_, so a commit made while a cut holds mu_ does not wait for the cut).
  struct Seen {
    uint64_t content = 0;             // changes that were not labels only (and drops)
    std::array<uint64_t, 32> bits{};  // changes that flipped each label bit
    uint64_t lsn = 0;                 // the highest LSN seen (or read at subscription)
  };
  Seen seen() {
    std::lock_guard<std::mutex> l(ev_mu_);
    return seen_;
  }
  void Watch(Dataset& ds);  // (re)subscribes to ds unless watching it already
  uint32_t Find(uint64_t id) const;  // the node of point `id`, UINT32_MAX if none
  // After a read of the whole region (its points `pts`): keeps the graph if those are its
  // points, else builds it (none above max_points_); notes what the graph was read from.
  Status Prepare(Dataset& ds, const GraphCutRequest& req, const std::vector<Point>& pts,
                 const Seen& seen0);

  std::mutex mu_;
  size_t max_points_;
  std::array<uint64_t, 2> fingerprint_{};  // of the points (not labels) and the parameters
  std::vector<std::pair<uint64_t, uint32_t>> nodes_;  // (point id, node), sorted
  // The same as a table indexed by id - dense_base_, when the ids are that dense (they are
  // given out in sequence): a re-cut maps a million points in milliseconds, not 100 ms.
  uint64_t dense_base_ = 0;
  std::vector<uint32_t> dense_;
  std::unique_ptr<GraphCut> graph_;
  // For re-cuts that read only labels: the graph's dataset, region and parameters, each node's
  // point (frame, id), Seen::content when its points were read (kStale: unknown), and which
  // nodes carried out_bit_ after the last cut (valid while Seen::bits[out_bit_] == out_count_).
  static constexpr uint64_t kStale = ~uint64_t{0};
  const Dataset* ds_ = nullptr;
  Region roi_;
  GraphCutParams params_;
  std::vector<std::pair<uint32_t, uint64_t>> keys_;  // (frame, id)
  uint64_t content_ = kStale;
  int out_bit_ = -1;
  uint64_t out_count_ = kStale;
  std::vector<uint8_t> has_out_;
  std::mutex ev_mu_;
  Seen seen_;
  std::unique_ptr<WatchHandle> watch_;
  const Dataset* watched_ = nullptr;
};

// With a cache, a cut over the same points as the cached one is a re-cut.
Result<GraphCutReply> GraphCutSelect(Dataset& ds, const GraphCutRequest& req,
                                     GraphCutCache* cache = nullptr);

// What a clipboard holds: points as they were stored and, copied from a Gaussian-splat
// dataset, each one's Gaussian record (null otherwise).
struct Clip {
  std::vector<Point> points;
  std::shared_ptr<const GaussianColumns> gaussians;
};

// Named clipboards, kept as files DIR/clipboards/<name>.hvc (docs/FORMAT.md), so that they
// survive sessions and are shared by the server and the embedded CLI.
class ClipboardStore {
 public:
  // env: the data directory's store (a server's RADOS pool, so that all its servers share
  // clipboards); null: the POSIX files.
  explicit ClipboardStore(std::string data_dir, Env* env = nullptr)
      : dir_(std::move(data_dir) + "/clipboards"), env_(env ? env : Env::Default()) {}
  // gaussians: a record per point, or null.
  Status Put(const std::string& name, const std::vector<Point>& points,
             const GaussianColumns* gaussians = nullptr);
  Result<Clip> Get(const std::string& name) const;
  std::vector<std::string> List() const;

 private:
  std::string dir_;
  Env* env_;
};

// Copies the points carrying `bit` (within `region`, if given) to the clipboard; with `cut`,
// deletes them in the same step. Returns the number of points and the commit (cut only).
struct CopyResult {
  uint64_t points = 0;
  uint64_t lsn = 0;
};
// The requests of Copy, Paste and Composite as values (the executor's, service/service.h, and
// the wire's, protocol/convert.h).
struct CopyRequest {
  int bit = 0;
  std::optional<Region> region;  // restricts the copy; absent: the whole dataset
  std::string clipboard;
  bool cut = false;  // also delete the copied points, in the same transaction
};
struct PasteRequest {
  std::string clipboard;
  Affine4 map;
};
struct CompositeRequest {
  std::vector<Point> object;
  uint32_t first_frame = 0, frame_count = 1;
  std::vector<std::array<double, 3>> trajectory;  // metres per frame, or empty (static)
  // A record per object point (a splat file's), or null: see Composite.
  std::shared_ptr<const GaussianColumns> gaussians = nullptr;
};
Result<CopyResult> Copy(Dataset& ds, int bit, const std::optional<Region>& region,
                        ClipboardStore& store, const std::string& clipboard, bool cut);

// Inserts the clipboard's points into `ds` moved by `map` (new ids; frames follow the new t).
// Into a Gaussian-splat dataset, splats with records keep them, turned and scaled with `map`
// as a transform turns stored splats (GaussianRecordMap).
Result<CommitInfo> Paste(Dataset& ds, const Clip& clip, const Affine4& map);

// Inserts an object (e.g. a PLY point cloud) into frames first .. first + count - 1: static, or
// offset by trajectory[i] (metres) in frame first + i. Into a Gaussian-splat dataset an object
// with `gaussians` (a record per point: a splat file) keeps them in every frame.
Result<CommitInfo> Composite(Dataset& ds, const std::vector<Point>& object, uint32_t first,
                             uint32_t count,
                             const std::vector<std::array<double, 3>>& trajectory = {},
                             const GaussianColumns* gaussians = nullptr);

// Projects a 3D point through a pinhole camera (no distortion): false if behind it.
bool ProjectToPixel(const CameraInfo& cam, double x, double y, double z, double* u, double* v,
                    double* depth);

}  // namespace hvdb::edit

#endif  // HVDB_EDIT_OPERATORS_H_
