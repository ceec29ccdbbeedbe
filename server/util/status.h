// Status: the outcome of an operation that can fail in an expected way (a missing or corrupt file,
// an unsupported layout, a hostile message). Either OK, or a code plus a human-readable message
// that names the object and the problem ("corrupt: a.tif: strip 3 is truncated").
//
// Thread safety: a Status is an immutable value; copies may be used from any thread.
#ifndef OCTOSCOPE_UTIL_STATUS_H_
#define OCTOSCOPE_UTIL_STATUS_H_

#include <string>
#include <string_view>
#include <utility>

namespace octoscope {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,    // The caller asked for something that makes no sense.
  kNotFound,           // A file, series, channel … does not exist.
  kCorrupt,            // Input data contradicts itself or its format.
  kUnsupported,        // Valid input we do not handle (yet).
  kIoError,            // The operating system refused a read or write.
  kOutOfRange,         // An index or size lies outside what is allowed.
  kResourceExhausted,  // A limit (memory budget, size cap) would be exceeded.
  kCancelled,          // The operation was stopped on request.
  kInternal,           // A bug: an invariant of ours does not hold.
  kUnavailable,        // Held by another process (a locked cache directory); may work later.
  // The object's state does not allow the operation (a slab for a finished acquisition).
  kFailedPrecondition,
  // The caller may not touch the object (a file outside the folder a dataset may read).
  kPermissionDenied,
};

std::string_view StatusCodeName(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;  // OK.
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status Ok() { return Status(); }

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }

  // Returns a copy whose message is "context: message" (keeps the code).
  Status WithContext(std::string_view context) const;

  // "OK" or "<code name>: <message>".
  std::string ToString() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

Status InvalidArgumentError(std::string message);
Status NotFoundError(std::string message);
Status CorruptError(std::string message);
Status UnsupportedError(std::string message);
Status IoError(std::string message);
Status OutOfRangeError(std::string message);
Status ResourceExhaustedError(std::string message);
Status CancelledError(std::string message);
Status InternalError(std::string message);
Status UnavailableError(std::string message);
Status FailedPreconditionError(std::string message);
Status PermissionDeniedError(std::string message);

// Returns from the enclosing function when `expr` (a Status) is not OK.
#define OCTO_RETURN_IF_ERROR(expr)               \
  do {                                           \
    ::octoscope::Status octo_status_ = (expr);   \
    if (!octo_status_.ok()) return octo_status_; \
  } while (0)

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_STATUS_H_
