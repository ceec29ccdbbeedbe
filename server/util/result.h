// Result<T>: either a value of type T or a non-OK Status explaining why there is none.
//
// Thread safety: like std::optional — distinct objects may be used concurrently; one object
// must not be mutated concurrently.
#ifndef OCTOSCOPE_UTIL_RESULT_H_
#define OCTOSCOPE_UTIL_RESULT_H_

#include <cstdio>
#include <cstdlib>
#include <utility>
#include <variant>

#include "util/status.h"

namespace octoscope {

template <typename T>
class [[nodiscard]] Result {
 public:
  // Implicit on purpose, so functions can `return value;` or `return SomeError(...);`.
  Result(T value) : data_(std::move(value)) {}        // NOLINT
  Result(Status status) : data_(std::move(status)) {  // NOLINT
    // An OK status carries no value: that is a bug in the caller.
    if (std::get<Status>(data_).ok()) data_ = InternalError("Result constructed from OK status");
  }

  bool ok() const { return std::holds_alternative<T>(data_); }
  // The error; Status::Ok() when a value is present.
  Status status() const { return ok() ? Status::Ok() : std::get<Status>(data_); }

  // REQUIRES: ok().
  T& value() & { return Get(); }
  const T& value() const& { return const_cast<Result*>(this)->Get(); }
  T&& value() && { return std::move(Get()); }
  T& operator*() & { return Get(); }
  const T& operator*() const& { return const_cast<Result*>(this)->Get(); }
  T* operator->() { return &Get(); }
  const T* operator->() const { return &const_cast<Result*>(this)->Get(); }

 private:
  T& Get() {
    if (!ok()) {
      // Reading a missing value is a programming error, never an expected failure.
      std::fprintf(stderr, "Result::value() on error: %s\n",
                   std::get<Status>(data_).ToString().c_str());
      std::abort();
    }
    return std::get<T>(data_);
  }

  std::variant<T, Status> data_;
};

#define OCTO_CONCAT_INNER_(a, b) a##b
#define OCTO_CONCAT_(a, b) OCTO_CONCAT_INNER_(a, b)

// Evaluates `expr` (a Result<T>); on error returns its Status, else moves the value into `lhs`.
//   OCTO_ASSIGN_OR_RETURN(auto file, TiffFile::Open(path));
#define OCTO_ASSIGN_OR_RETURN(lhs, expr) \
  OCTO_ASSIGN_OR_RETURN_IMPL_(OCTO_CONCAT_(octo_result_, __LINE__), lhs, expr)
#define OCTO_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                                \
  if (!tmp.ok()) return tmp.status();               \
  lhs = std::move(tmp).value()

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_RESULT_H_
