// The frames a raw socket test read from the server, split as docs/PROTOCOL.md ("Framing") says.
#ifndef HVDB_TESTS_SERVER_FRAMES_H_
#define HVDB_TESTS_SERVER_FRAMES_H_

#include <string>
#include <vector>

#include "protocol/wire.h"

namespace hvdb::testing {

// The message of every whole frame in `bytes`, in order (a cut-off last frame is left out).
inline std::vector<std::string> FramePayloads(const std::string& bytes) {
  std::vector<std::string> out;
  wire::FrameReader reader(256u << 20);
  reader.Feed(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
  std::string payload, err;
  while (reader.Next(&payload, &err) == wire::FrameReader::Result::kFrame) out.push_back(payload);
  return out;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_SERVER_FRAMES_H_
