// The request table: every kind of request the wire protocol carries, in one list
// (HVDB_REQUESTS), with what the server's sessions and the remote client need to know of it —
// its name, whether it writes, how it flows, whether a client may repeat it after a lost
// connection — and, for the requests the executor answers in one reply, the one pair that maps
// the wire message to the executor's typed call and back (op::NAME). As SQLite's opcode table
// and DuckDB's function registry do: a new request is one row and one op, and hvdb-server's
// dispatch, its session bookkeeping and the remote backend all read them (docs/ARCHITECTURE.md,
// "Adding a request").
//
// This header and requests.cc form the library hvdb_requests: the wire codec only (protocol/),
// so that a remote-only client links no engine. The executor's side, op::NAME::Run and
// ExecuteUnary, is in execute.cc (hvdb_service).
#ifndef HVDB_SERVICE_REQUESTS_H_
#define HVDB_SERVICE_REQUESTS_H_

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "edit/operators.h"
#include "media/media.h"
#include "protocol/convert.h"
#include "protocol/wire.h"
#include "storage/database.h"

namespace hvdb::service {

class Service;

// How a request flows on a connection.
enum class Flow {
  kConnection,  // the connection's own business (ping, cancel, slot release): no executor call
  kUnary,       // one request, one reply, from the executor (op::NAME): run on a worker
  kStream,      // several messages (query batches, render images, ingest chunks, watch events):
                // the session's stream handlers, around the executor's call
};

// One row of the table.
struct RequestKind {
  int body = 0;              // wire::Request::BodyCase
  const char* name = "";     // as stats, logs and errors name it ("query", "graph_cut", ...)
  bool writes = false;       // needs a read-write connection; a reader refuses it (NOT_LEADER)
  Flow flow = Flow::kUnary;
  // Safe for a client to send again after the connection broke (nothing applied twice). An
  // op may refine this by its value (op::Copy: a cut is not).
  bool repeatable = false;
  // For requests that carry a file or an object whole: what to do when the server's frame
  // limit (--max-frame-bytes) refuses it; nullptr: such requests are small.
  const char* if_too_large = nullptr;
};

// The table: one X(...) row per request kind —
//   X(op name, wire body case, name, writes, flow, repeatable, if_too_large)
// Nothing else in product code lists the kinds.
#define HVDB_REQUESTS(X)                                                                        \
  X(Ping, kPing, "ping", false, kConnection, true, nullptr)                                     \
  X(Cancel, kCancel, "cancel", false, kConnection, true, nullptr)                               \
  X(Release, kRelease, "release", false, kConnection, true, nullptr)                            \
  X(List, kList, "list", false, kUnary, true, nullptr)                                          \
  X(Create, kCreate, "create", true, kUnary, false, nullptr)                                    \
  X(Drop, kDrop, "drop", true, kUnary, false, nullptr)                                          \
  X(Describe, kDescribe, "describe", false, kUnary, true, nullptr)                              \
  X(Query, kQuery, "query", false, kStream, true, nullptr)                                      \
  X(Edit, kEdit, "edit", true, kUnary, false, nullptr)                                          \
  X(Revert, kRevert, "revert", true, kUnary, false, nullptr)                                    \
  X(Ingest, kIngest, "ingest", true, kStream, false, nullptr)                                   \
  X(Stats, kStats, "stats", false, kUnary, true, nullptr)                                       \
  X(ServerStats, kServerStats, "server_stats", false, kUnary, true, nullptr)                    \
  X(Render, kRender, "render", false, kStream, true, nullptr)                                   \
  X(PutPhoto, kPutPhoto, "put_photo", true, kUnary, true, nullptr)                              \
  X(Watch, kWatch, "watch", false, kStream, true, nullptr)                                      \
  X(Select, kSelect, "select", true, kUnary, false, nullptr)                                    \
  X(GraphCut, kGraphCut, "graph_cut", true, kUnary, false, nullptr)                             \
  X(Copy, kCopy, "copy", true, kUnary, true, nullptr)                                           \
  X(Paste, kPaste, "paste", true, kUnary, false, nullptr)                                       \
  X(Composite, kComposite, "composite", true, kUnary, false,                                    \
    "thin the object out, or composite it in parts")                                           \
  X(ImportMedia, kImportMedia, "import_media", true, kUnary, false,                             \
    "import it with --data on the server's machine, or make it smaller")                       \
  X(Compact, kCompact, "compact", true, kUnary, true, nullptr)                                  \
  X(ReadGaussians, kReadGaussians, "read_gaussians", false, kUnary, true, nullptr)

// Every row, in the table's order.
std::span<const RequestKind> Requests();
// The row of a request's kind; a body this build does not know gets a row named "unknown"
// (flow kConnection, so that no executor call is made for it).
const RequestKind& KindOf(const wire::Request& r);

// ---- What an hvdb-server reports of itself (server_stats; the counters of stats).

// Latency of one kind of request, over the server's recent requests of that kind.
struct RequestLatency {
  std::string kind;  // a row's name ("query", "edit", ...), or "ingest_chunk"
  uint64_t count = 0;
  double p50_ms = 0, p95_ms = 0, p99_ms = 0;
};

struct ServerCounters {
  uint64_t connections_open = 0, connections_total = 0;
  std::vector<RequestLatency> requests;  // sorted by kind
  uint64_t bytes_in = 0, bytes_out = 0;
  double cache_hit_rate = 0;  // 0..1
  uint64_t cache_capacity_bytes = 0;
  std::string role;    // "writer", or "reader" (follows the writer; refuses writes)
  std::string leader;  // where the writer listens, as it published it
  uint64_t buffered_bytes = 0;       // results buffered for all connections now
  uint64_t memory_budget_bytes = 0;  // the server's --memory-budget
};

// What Stats reports of one dataset.
struct DatasetReport {
  DatasetStats stats;
  uint64_t last_lsn = 0;
};

// ---- The unary requests' values and their wire pairs. Each op has
//   In, Out                  the executor's values (service.h's signatures)
//   Dataset(in)              the dataset it names ("" for none), for errors
//   Repeatable(in)           the row's flag, refined by the value where it depends on it
//   Put(in, req) / Take(req)          the request, to and from the wire
//   PutReply(out, resp) / TakeReply(resp)   the reply, to and from the wire
//   Run(service, in)         the executor's call (execute.cc)
// Take checks the shape of a message only; whether the values make sense is the executor's.

struct Empty {};

// A request's value together with the dataset it is for.
template <typename T>
struct On {
  std::string dataset;
  T value{};
};

struct PhotoUpload {
  uint32_t frame = 0;
  Photo photo;
};

// stats: the server's counters (the embedded mode's block cache only) and, when a dataset was
// named, its storage statistics.
struct StatsOut {
  ServerCounters server;
  std::optional<DatasetReport> dataset;
};

// read_gaussians: the stored records of ids; found[i] false where id i has none (its record is
// zero: DeriveMissing fills it from the point).
struct GaussianRead {
  GaussianColumns records;
  std::vector<bool> found;
};
// The most ids one read_gaussians request may name: its reply, 7.4 MiB at degree 3, stays
// within a server's default frame limit (16 MiB).
inline constexpr size_t kMaxGaussianReadIds = size_t{1} << 15;
// And the most blocks of 1024 records its ids may touch (each is read whole: up to 236 MiB
// read for one request). Ids in ascending runs touch few; Backend::ReadGaussians sends them so.
inline constexpr size_t kMaxGaussianReadBlocks = 1024;

namespace op {

#define HVDB_OP(NAME, IN, OUT)                                             \
  struct NAME {                                                            \
    using In = IN;                                                         \
    using Out = OUT;                                                       \
    static const RequestKind& Kind();                                      \
    static std::string Dataset(const In& in);                              \
    static bool Repeatable(const In& in);                                  \
    static void Put(const In& in, wire::Request* req);                     \
    static Result<In> Take(const wire::Request& req);                      \
    static void PutReply(const Out& out, wire::Response* resp);            \
    static Result<Out> TakeReply(const wire::Response& resp);              \
    static Result<Out> Run(Service& x, const In& in);                      \
  };

HVDB_OP(List, Empty, std::vector<std::string>)
HVDB_OP(Create, DatasetInfo, DatasetInfo)
HVDB_OP(Drop, std::string, Empty)
HVDB_OP(Describe, std::string, DatasetInfo)
HVDB_OP(Edit, On<Transaction>, CommitInfo)
HVDB_OP(Revert, On<uint64_t>, CommitInfo)
HVDB_OP(Stats, std::string, StatsOut)
HVDB_OP(ServerStats, Empty, ServerCounters)
HVDB_OP(PutPhoto, On<PhotoUpload>, Empty)
HVDB_OP(Select, On<edit::SelectRequest>, edit::SelectResult)
HVDB_OP(GraphCut, On<edit::GraphCutRequest>, edit::GraphCutReply)
HVDB_OP(Copy, On<edit::CopyRequest>, edit::CopyResult)
HVDB_OP(Paste, On<edit::PasteRequest>, CommitInfo)
HVDB_OP(Composite, On<edit::CompositeRequest>, CommitInfo)
HVDB_OP(ImportMedia, On<media::ImportRequest>, CommitInfo)
HVDB_OP(Compact, On<wire::CompactArgs>, CompactInfo)
HVDB_OP(ReadGaussians, On<std::vector<uint64_t>>, GaussianRead)

#undef HVDB_OP

}  // namespace op

// The counters to and from the wire (the server_stats reply; the same fields of StatsReply).
void ToWire(const ServerCounters& c, wire::ServerCounters* out);
ServerCounters FromWire(const wire::ServerCounters& c);

// A unary request's reply: decoded with the op's pair, run on the executor, encoded; an error of
// either step is the error response. MALFORMED for a kind that is not unary.
wire::Response ExecuteUnary(Service& x, const wire::Request& req);

// A Status as an error response: a dataset that does not exist is UNKNOWN_DATASET, the rest by
// their code (wire::ToWire), unless `code` says otherwise.
wire::Response ErrorResponse(uint64_t id, const Status& st,
                             wire::ErrorCode code = wire::ERROR_UNSPECIFIED);

// A NotFound for a dataset that does not exist (wire: UNKNOWN_DATASET, not NOT_FOUND).
Status UnknownDataset(const std::string& name);
bool IsUnknownDataset(const Status& s);

}  // namespace hvdb::service

#endif  // HVDB_SERVICE_REQUESTS_H_
