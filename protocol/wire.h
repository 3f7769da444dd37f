// The hvdb wire protocol: framing and conversions between engine values and messages.
// docs/PROTOCOL.md is the specification; hvdb.proto holds the message bodies.
//
// Framing: every frame is a 4-byte little-endian word W, the message length L = W & 0x7fffffff,
// and, when bit 31 of W is set, a 4-byte little-endian attachment length A; then L bytes of a
// serialized protobuf message (Hello/HelloReply first, then Request / Response) and A bytes of
// attachment (the raw point records of a RECORDS batch). Only the server sends attachments.
#ifndef HVDB_PROTOCOL_WIRE_H_
#define HVDB_PROTOCOL_WIRE_H_

#include <cstdint>
#include <span>
#include <utility>
#include <string>
#include <vector>

#include "protocol/hvdb.pb.h"
#include "storage/database.h"
#include "storage/gaussian_column.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::wire {

inline constexpr uint32_t kProtocolVersion = 2;
inline constexpr uint32_t kFrameHeaderSize = 4;
inline constexpr uint32_t kAttachmentFlag = 1u << 31;
inline constexpr uint32_t kAttachmentHeaderSize = 4;
inline constexpr uint32_t kDefaultMaxFrame = 16u << 20;
// Results are streamed in batches of at most this many bytes of point data.
inline constexpr uint32_t kMaxBatchBytes = 1u << 20;
inline constexpr uint32_t kMaxBatchPoints = kMaxBatchBytes / 64;

// Appends a frame holding `msg` to `out`.
void AppendFrame(const google::protobuf::MessageLite& msg, std::string* out);
std::string Frame(const google::protobuf::MessageLite& msg);
// The header and message of a frame whose attachment (attachment_len bytes) the caller sends
// right after it, e.g. with scatter/gather from where the records already lie.
std::string FrameHead(const google::protobuf::MessageLite& msg, uint32_t attachment_len);

// Incremental frame splitter: feed bytes, take whole payloads out. Needs no socket, so the
// fuzzer and the tests drive it directly.
class FrameReader {
 public:
  explicit FrameReader(uint32_t max_frame = kDefaultMaxFrame) : max_frame_(max_frame) {}
  enum class Result { kFrame, kNeedMore, kBad };
  void Feed(const uint8_t* data, size_t n) { buf_.append(reinterpret_cast<const char*>(data), n); }
  // kFrame: *payload holds the next frame's message and *attachment (if given) its attachment
  // (empty if none). kBad: a length is over the limit, or an attachment came where none may
  // (attachment == nullptr); *error says which. The stream cannot be resynchronised.
  Result Next(std::string* payload, std::string* error, std::string* attachment = nullptr);

 private:
  uint32_t max_frame_;
  std::string buf_;
  size_t pos_ = 0;
};

// Message length and attachment flag from a frame's first word; false when the length exceeds
// max_frame (*len is set either way).
bool ParseFrameHeader(const uint8_t header[4], uint32_t max_frame, uint32_t* len,
                      bool* has_attachment = nullptr);

// ---- Points ----
void EncodeColumns(std::span<const Point> pts, PointColumns* out);
Status DecodeColumns(const PointColumns& in, std::vector<Point>* out);
// Gaussian records [first, first + n) of `cols`.
void EncodeGaussians(const GaussianColumns& cols, size_t first, size_t n, GaussianRecords* out);
// Appends the message's records to *out: its degree when *out is empty, else the same one.
// InvalidArgument when the bytes are not `count` records of that degree.
Status DecodeGaussians(const GaussianRecords& in, GaussianColumns* out);
// Draco: positions quantised to `position_bits` and colours to 8 bits; ids and frames exact.
Status EncodeDraco(std::span<const Point> pts, int position_bits, std::string* out);
Status DecodeDraco(const std::string& data, std::vector<Point>* out);
// HVDB7: one progressive hvdb7 stream (codec/) of the attributes `params` names (every one when
// it names none); `params` as Query.codec
// (zeros take the defaults). Out-of-range parameters are InvalidArgument naming the field.
Status EncodeHvdb7(std::span<const Point> pts, const CodecParams& params, std::string* out);
Status CheckHvdb7Params(const CodecParams& params);
// Appends the decoded points to *out.
Status DecodeHvdb7(const std::string& data, std::vector<Point>* out);

// ---- Values ----
void ToWire(const hvdb::Region& r, wire::Region* out);
Result<hvdb::Region> FromWire(const wire::Region& r);
void ToWire(const hvdb::DatasetInfo& info, wire::DatasetInfo* out);
hvdb::DatasetInfo FromWire(const wire::DatasetInfo& info);
void ToWire(const CameraInfo& c, wire::Camera* out);
Result<CameraInfo> FromWire(const wire::Camera& c);
void ToWire(const hvdb::Selection& s, wire::Selection* out);
Result<hvdb::Selection> FromWire(const wire::Selection& s);
// Builds an engine transaction from an Edit request (validating every field).
Result<Transaction> FromWire(const wire::Edit& e);
void ToWire(const Transaction& t, wire::Edit* out);

// ---- Errors ----
ErrorCode ToWire(StatusCode code);
StatusCode FromWire(ErrorCode code);
void ToWire(const Status& s, wire::Error* out);
Status FromWire(const wire::Error& e);

}  // namespace hvdb::wire

#endif  // HVDB_PROTOCOL_WIRE_H_
