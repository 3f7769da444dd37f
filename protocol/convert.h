// ToWire / FromWire pairs for the executor's request and reply values (service/service.h):
// the editing operators of edit/operators.h, commit results, storage statistics and query
// options. Each pair round-trips (tests/protocol/convert_test.cc). FromWire decodes the shape
// of a message only (counts, known enum values); whether the values make sense is the
// executor's to say, once, for embedded and remote callers alike.
#ifndef HVDB_PROTOCOL_CONVERT_H_
#define HVDB_PROTOCOL_CONVERT_H_

#include "edit/operators.h"
#include "media/media.h"
#include "protocol/wire.h"

namespace hvdb::wire {

// Label bits travel as uint32; a negative bit (an int) comes back as the same negative number,
// so that the executor refuses it with the number the caller gave.
uint32_t BitToWire(int bit);
int BitFromWire(uint32_t bit);

void ToWire(const edit::SelectRequest& r, wire::SelectRequest* out);
Result<edit::SelectRequest> FromWire(const wire::SelectRequest& r);
void ToWire(const edit::SelectResult& r, wire::SelectReply* out);
Result<edit::SelectResult> FromWire(const wire::SelectReply& r);

void ToWire(const edit::GraphCutRequest& r, wire::GraphCutRequest* out);
Result<edit::GraphCutRequest> FromWire(const wire::GraphCutRequest& r);
void ToWire(const edit::GraphCutReply& r, wire::GraphCutReply* out);
edit::GraphCutReply FromWire(const wire::GraphCutReply& r);

void ToWire(const edit::CopyRequest& r, wire::CopyRequest* out);
Result<edit::CopyRequest> FromWire(const wire::CopyRequest& r);
void ToWire(const edit::CopyResult& r, wire::CopyReply* out);
edit::CopyResult FromWire(const wire::CopyReply& r);

void ToWire(const edit::PasteRequest& r, wire::PasteRequest* out);
Result<edit::PasteRequest> FromWire(const wire::PasteRequest& r);

void ToWire(const edit::CompositeRequest& r, wire::CompositeRequest* out);
Result<edit::CompositeRequest> FromWire(const wire::CompositeRequest& r);

// An unknown kind, or `at` / `rotate` with other than 3 values, is refused.
void ToWire(const media::ImportRequest& r, wire::ImportMediaRequest* out);
Result<media::ImportRequest> FromWire(const wire::ImportMediaRequest& r);

void ToWire(const CommitInfo& c, wire::CommitReply* out);
CommitInfo FromWire(const wire::CommitReply& c);

void ToWire(const hvdb::DatasetStats& s, wire::DatasetStats* out);
hvdb::DatasetStats FromWire(const wire::DatasetStats& s);
void ToWire(const hvdb::CompactInfo& c, wire::CompactReply* out);
hvdb::CompactInfo FromWire(const wire::CompactReply& c);
// What a compaction asks for: the frame range [first, last] ([0, 2^32 - 1] for `all`), and
// whether it codes the photos as video instead of compressing the points.
struct CompactArgs {
  uint32_t first = 0, last = 0;
  bool photos = false;
};
Result<CompactArgs> FromWire(const wire::CompactRequest& c);

// The dataset a CreateDataset request asks for (space_time_scale 0 on the wire: 1 m/s).
void ToWire(const hvdb::DatasetInfo& info, wire::CreateDataset* out);
Result<hvdb::DatasetInfo> FromWire(const wire::CreateDataset& c);

// A photo of PutPhoto (its dataset and frame travel beside it); a billboard with other than 3
// plane values is refused, the rest is storage's to judge (ValidatePhoto).
void ToWire(const Photo& p, wire::PutPhoto* out);
Result<Photo> FromWire(const wire::PutPhoto& p);

// A query's options (the region and dataset travel beside them in wire::Query). batch_points 0
// on the wire is the server's default; the encoding is the transport's business, not here.
void ToWire(const QueryOptions& o, wire::Query* out);
Result<QueryOptions> QueryOptionsFromWire(const wire::Query& q);

// A watch's event (storage/watch.h). The kinds map one to one; an unknown kind from a newer
// server is InvalidArgument.
void ToWire(const ChangeEvent& e, wire::WatchEvent* out);
Result<ChangeEvent> FromWire(const wire::WatchEvent& e);

}  // namespace hvdb::wire

#endif  // HVDB_PROTOCOL_CONVERT_H_
