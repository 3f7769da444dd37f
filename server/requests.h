// The unary requests, decoded into the executor's values (protocol/convert.h), run by the one
// executor (service/service.h) and its reply encoded: the server's side of "decode at the edge,
// execute once". Streams (queries, renders, ingest chunks) are the session's (session_stream.cc).
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
// A Status as an error response: a dataset that does not exist is UNKNOWN_DATASET, the rest
// by their code (wire::ToWire), unless `code` says otherwise.
wire::Response ErrorResponse(uint64_t id, const Status& st,
                             wire::ErrorCode code = wire::ERROR_UNSPECIFIED);
// Whether Execute serves this kind (on a worker: it may read and write the data).
bool IsUnary(const wire::Request& r);
// List, Create, Drop, Describe, Edit, Revert, PutPhoto and the editing operators. (Stats is the
// session's: it adds the server's counters to the executor's Service::Stats.)
wire::Response Execute(Server* s, uint64_t id, const wire::Request& req);

}  // namespace hvdb::server

#endif  // HVDB_SERVER_REQUESTS_H_
