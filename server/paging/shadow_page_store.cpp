#include "paging/shadow_page_store.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <optional>
#include <vector>

#include "util/durable_file.h"

namespace octoscope::paging {
namespace {

namespace fs = std::filesystem;

constexpr char kShadowMagic[8] = {'O', 'C', 'T', 'O', 'S', 'H', 'D', 'W'};
constexpr char kMapMagic[8] = {'O', 'C', 'T', 'O', 'S', 'M', 'A', 'P'};
constexpr uint32_t kVersion = 1;
constexpr uint64_t kHeaderBytes = 40;
constexpr uint64_t kMapHeaderBytes = 40;

void PutU64(std::string& out, uint64_t v) {
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<char>(v >> (8 * i)));
}

uint64_t GetU64(std::string_view in, size_t at) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i)
    v |= static_cast<uint64_t>(static_cast<uint8_t>(in[at + i])) << (8 * i);
  return v;
}

// magic, u32 version, u32 0, u64 a, u64 b: the first 32 bytes of a shadow file or a map.
std::string Prefix(const char (&magic)[8], uint64_t a, uint64_t b) {
  std::string out(magic, sizeof magic);
  PutU64(out, kVersion);  // u32 version + u32 0.
  PutU64(out, a);
  PutU64(out, b);
  return out;
}

std::string ShadowHeader(uint64_t generation, uint64_t page_bytes) {
  std::string header = Prefix(kShadowMagic, generation, page_bytes);
  PutU64(header, Fnv1a64(header));
  return header;
}

uint64_t SlotOffset(uint64_t slot, uint64_t page_bytes) { return kHeaderBytes + slot * page_bytes; }

Status OsError(const fs::path& path, const char* step) {
  return IoError(path.string() + ": " + step + ": " + std::strerror(errno));
}

Status PwriteAll(int fd, const fs::path& path, std::span<const std::byte> data, uint64_t offset) {
  size_t done = 0;
  while (done < data.size()) {
    const ssize_t n =
        ::pwrite(fd, data.data() + done, data.size() - done, static_cast<off_t>(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      if (n == 0) errno = ENOSPC;
      return OsError(path, "pwrite");
    }
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

// Reads out.size() bytes at `offset`; kCorrupt when the file ends first.
Status PreadAll(int fd, const fs::path& path, std::span<std::byte> out, uint64_t offset) {
  size_t done = 0;
  while (done < out.size()) {
    const ssize_t n =
        ::pread(fd, out.data() + done, out.size() - done, static_cast<off_t>(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return OsError(path, "pread");
    if (n == 0) return CorruptError(path.string() + ": shorter than its slots");
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

// The shadow file's generation, or nullopt when it is missing, short or of another page size.
std::optional<uint64_t> ShadowGeneration(int fd, uint64_t page_bytes) {
  char bytes[kHeaderBytes];
  if (::pread(fd, bytes, sizeof bytes, 0) != static_cast<ssize_t>(sizeof bytes)) {
    return std::nullopt;
  }
  const std::string_view header(bytes, sizeof bytes);
  const uint64_t generation = GetU64(header, 16);
  if (header != ShadowHeader(generation, page_bytes)) return std::nullopt;
  return generation;
}

struct Fd {
  int fd = -1;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

}  // namespace

std::string ShadowMap::Serialize() const {
  std::string out = Prefix(kMapMagic, generation, page_bytes);
  PutU64(out, slots.size());
  for (const auto& [page, slot] : slots) {
    PutU64(out, page);
    PutU64(out, slot);
  }
  return out;
}

Result<ShadowMap> ShadowMap::Parse(std::string_view bytes) {
  auto bad = [](const std::string& what) { return CorruptError("shadow map: " + what); };
  if (bytes.size() < kMapHeaderBytes || bytes.substr(0, 8) != std::string_view(kMapMagic, 8)) {
    return bad("not a shadow map");
  }
  if (GetU64(bytes, 8) != kVersion) return bad("version " + std::to_string(GetU64(bytes, 8)));
  ShadowMap map;
  map.generation = GetU64(bytes, 16);
  map.page_bytes = GetU64(bytes, 24);
  const uint64_t count = GetU64(bytes, 32);
  if (map.page_bytes == 0 || count > (bytes.size() - kMapHeaderBytes) / 16 ||
      bytes.size() != kMapHeaderBytes + count * 16) {
    return bad("size does not match its count");
  }
  for (uint64_t i = 0; i < count; ++i) {
    const uint64_t page = GetU64(bytes, kMapHeaderBytes + 16 * i);
    const uint64_t slot = GetU64(bytes, kMapHeaderBytes + 16 * i + 8);
    if (slot >= count || (!map.slots.empty() && page <= map.slots.rbegin()->first)) {
      return bad("entry " + std::to_string(i) + " is out of order or range");
    }
    map.slots.emplace(page, slot);
  }
  return map;
}

Result<std::unique_ptr<ShadowPageStore>> ShadowPageStore::Create(std::unique_ptr<PageStore> inner,
                                                                 const fs::path& shadow_path,
                                                                 uint64_t generation) {
  const int fd = ::open(shadow_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return OsError(shadow_path, "open the shadow file");
  std::unique_ptr<ShadowPageStore> store(new ShadowPageStore(std::move(inner), shadow_path, fd));
  std::lock_guard<std::mutex> lock(store->mu_);
  OCTO_RETURN_IF_ERROR(store->StartLocked(generation));
  OCTO_RETURN_IF_ERROR(
      SyncDirectory(shadow_path.has_parent_path() ? shadow_path.parent_path() : "."));
  return store;
}

ShadowPageStore::~ShadowPageStore() { ::close(fd_); }

Status ShadowPageStore::StartLocked(uint64_t generation) {
  const std::string header = ShadowHeader(generation, inner_->page_bytes());
  // Old slots go first; should the header reach the disk before the truncation does, they belong
  // to a generation no map names any more.
  if (::ftruncate(fd_, 0) != 0) return OsError(shadow_path_, "ftruncate");
  OCTO_RETURN_IF_ERROR(PwriteAll(fd_, shadow_path_, std::as_bytes(std::span(header)), 0));
  if (::fdatasync(fd_) != 0) return OsError(shadow_path_, "fdatasync");
  generation_ = generation;
  protected_ = inner_->page_count();
  slots_.clear();
  return Status::Ok();
}

Status ShadowPageStore::Read(uint64_t page, std::span<std::byte> out) {
  std::optional<uint64_t> slot;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (auto it = slots_.find(page); it != slots_.end()) slot = it->second;
  }
  if (!slot || out.size() != page_bytes()) return inner_->Read(page, out);
  return PreadAll(fd_, shadow_path_, out, SlotOffset(*slot, page_bytes()));
}

Status ShadowPageStore::Write(uint64_t page, std::span<const std::byte> data) {
  std::optional<uint64_t> slot;
  {
    std::lock_guard<std::mutex> lock(mu_);
    // A page of the checkpoint: its slot (the same for every write until the next checkpoint).
    if (page < protected_) slot = slots_.try_emplace(page, slots_.size()).first->second;
  }
  if (!slot || data.size() != page_bytes()) return inner_->Write(page, data);
  return PwriteAll(fd_, shadow_path_, data, SlotOffset(*slot, page_bytes()));
}

Status ShadowPageStore::Sync() {
  OCTO_RETURN_IF_ERROR(inner_->Sync());
  if (::fdatasync(fd_) != 0) return OsError(shadow_path_, "fdatasync");
  return Status::Ok();
}

ShadowMap ShadowPageStore::Freeze() const {
  std::lock_guard<std::mutex> lock(mu_);
  ShadowMap map;
  map.generation = generation_;
  map.page_bytes = inner_->page_bytes();
  map.slots = slots_;
  return map;
}

uint64_t ShadowPageStore::shadowed_pages() const {
  std::lock_guard<std::mutex> lock(mu_);
  return slots_.size();
}

Status ShadowPageStore::Apply(uint64_t generation) {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<std::byte> page(inner_->page_bytes());
  for (const auto& [index, slot] : slots_) {
    OCTO_RETURN_IF_ERROR(PreadAll(fd_, shadow_path_, page, SlotOffset(slot, page.size())));
    OCTO_RETURN_IF_ERROR(inner_->Write(index, page));
  }
  // The pool holds the new checkpoint before the shadow that could redo the copy is dropped.
  if (!slots_.empty()) OCTO_RETURN_IF_ERROR(inner_->Sync());
  return StartLocked(generation);
}

Result<uint64_t> ShadowPageStore::Recover(PageStore& inner, const fs::path& shadow_path,
                                          const ShadowMap& map) {
  Fd file{::open(shadow_path.c_str(), O_RDONLY | O_CLOEXEC)};
  if (file.fd < 0) {
    if (errno == ENOENT) return uint64_t{0};
    return OsError(shadow_path, "open the shadow file");
  }
  if (map.slots.empty() || map.page_bytes != inner.page_bytes() ||
      ShadowGeneration(file.fd, inner.page_bytes()) != map.generation) {
    return uint64_t{0};
  }
  std::vector<std::byte> page(inner.page_bytes());
  for (const auto& [index, slot] : map.slots) {
    OCTO_RETURN_IF_ERROR(PreadAll(file.fd, shadow_path, page, SlotOffset(slot, page.size())));
    OCTO_RETURN_IF_ERROR(inner.Write(index, page));
  }
  OCTO_RETURN_IF_ERROR(inner.Sync());
  return static_cast<uint64_t>(map.slots.size());
}

uint64_t ShadowPageStore::PagesWrittenSince(const fs::path& shadow_path, uint64_t generation) {
  Fd file{::open(shadow_path.c_str(), O_RDONLY | O_CLOEXEC)};
  if (file.fd < 0) return 0;
  char bytes[kHeaderBytes];
  if (::pread(file.fd, bytes, sizeof bytes, 0) != static_cast<ssize_t>(sizeof bytes)) return 0;
  const std::string_view header(bytes, sizeof bytes);
  const uint64_t page_bytes = GetU64(header, 24);
  if (page_bytes == 0 || header != ShadowHeader(generation, page_bytes)) return 0;
  std::error_code ec;
  const uint64_t size = fs::file_size(shadow_path, ec);
  return ec || size < kHeaderBytes ? 0 : (size - kHeaderBytes + page_bytes - 1) / page_bytes;
}

}  // namespace octoscope::paging
