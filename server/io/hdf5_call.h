// Checked HDF5 calls: every call of the HDF5 C library goes through OCTO_H5, which turns a failed
// call (a negative return) into a Status whose message keeps the call's source text and the most
// specific message of HDF5's error stack, e.g.
//   "H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT) failed: file signature not found".
// HDF5 prints its error stack to stderr by default; Hdf5Quiet() turns that off for the calling
// thread (HDF5 keeps one error stack per thread), and OCTO_H5 clears the stack after reading it.
// Identifiers (files, groups, datasets, types, spaces, property lists) are owned by Hdf5Id.
//
// Usage:
//   Hdf5Quiet();
//   OCTO_ASSIGN_OR_RETURN(hid_t raw, OCTO_H5(H5Dopen2(file, name, H5P_DEFAULT)));
//   Hdf5Id dataset(raw);
//
// Thread safety: thread-safe when the HDF5 library is (Debian builds it with --enable-threadsafe:
// one global lock); error stacks are per thread.
#ifndef OCTOSCOPE_IO_HDF5_CALL_H_
#define OCTOSCOPE_IO_HDF5_CALL_H_

#include <hdf5.h>

#include <string>
#include <string_view>
#include <utility>

#include "util/result.h"

namespace octoscope::io {

// Stops HDF5 from printing error stacks on the calling thread. Call before the first HDF5 call
// of every thread (cheap; idempotent).
void Hdf5Quiet();

// The failed call's Status: "<call_text> failed: <HDF5's innermost message>" (Corrupt: HDF5
// failures on a file we only read are almost always a damaged or unexpected file). Clears the
// calling thread's error stack.
Status Hdf5Error(std::string_view call_text);

template <typename T>
Result<T> Hdf5Checked(T value, std::string_view call_text) {
  if (value >= 0) return value;
  return Hdf5Error(call_text);
}

// Owns one HDF5 identifier; closes it (H5Idec_ref) on destruction. Move-only.
class Hdf5Id {
 public:
  Hdf5Id() = default;
  explicit Hdf5Id(hid_t id) : id_(id) {}
  ~Hdf5Id() { Reset(); }
  Hdf5Id(Hdf5Id&& other) noexcept : id_(std::exchange(other.id_, H5I_INVALID_HID)) {}
  Hdf5Id& operator=(Hdf5Id&& other) noexcept {
    if (this != &other) {
      Reset();
      id_ = std::exchange(other.id_, H5I_INVALID_HID);
    }
    return *this;
  }
  Hdf5Id(const Hdf5Id&) = delete;
  Hdf5Id& operator=(const Hdf5Id&) = delete;

  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  void Reset();

 private:
  hid_t id_ = H5I_INVALID_HID;
};

}  // namespace octoscope::io

// Evaluates an HDF5 call returning hid_t, herr_t or htri_t: a Result holding its value, or a
// Status naming the call when it failed (a negative value).
#define OCTO_H5(call) ::octoscope::io::Hdf5Checked((call), #call)

#endif  // OCTOSCOPE_IO_HDF5_CALL_H_
