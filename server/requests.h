// Request helpers shared by the session's files: request kinds, error responses, dataset lookup,
// and the editing operators (edit/operators.h) run against a dataset on a worker.
#ifndef HVDB_SERVER_REQUESTS_H_
#define HVDB_SERVER_REQUESTS_H_

#include <memory>
#include <string>

#include "protocol/wire.h"
#include "server/server.h"

namespace hvdb::server {

// The request's kind as stats and logs name it ("query", "edit", ...).
const char* KindOf(const wire::Request& r);
// Whether the request needs a read-write connection.
bool Writes(const wire::Request& r);
wire::Response ErrorResponse(uint64_t id, const Status& st,
                             wire::ErrorCode code = wire::ERROR_UNSPECIFIED);
// A dataset lookup failure is UNKNOWN_DATASET, not a generic NOT_FOUND.
Result<std::shared_ptr<Dataset>> FindDataset(Server* s, const std::string& name);
wire::Response DatasetError(uint64_t id, const Status& st);
wire::Response CommitResponse(uint64_t id, const CommitInfo& c);
// Select, GraphCut, Copy, Paste, Composite: runs on a worker.
wire::Response RunEditOperator(Server* s, uint64_t id, const wire::Request& req);

}  // namespace hvdb::server

#endif  // HVDB_SERVER_REQUESTS_H_
