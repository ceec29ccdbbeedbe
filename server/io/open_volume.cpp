#include "io/open_volume.h"

#include <optional>
#include <system_error>

#include "io/file_gate.h"
#include "io/ims_volume.h"
#include "io/ome_tiff_volume.h"
#include "io/ome_xml.h"
#include "io/ome_zarr_volume.h"
#include "io/raw_volume.h"
#include "io/slice_folder_volume.h"
#include "io/tiff_file.h"
#include "io/tiff_stack_volume.h"
#include "io/voreen_vvd.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

// The JSON sidecar that describes `raw`: "a.raw.json" first, then "a.json".
Result<std::optional<fs::path>> FindRawSidecar(const fs::path& raw, const FileGate& gate) {
  fs::path with_suffix = raw;
  with_suffix += ".json";
  fs::path replaced = raw;
  replaced.replace_extension(".json");
  for (const fs::path& sidecar : {with_suffix, replaced}) {
    OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(sidecar));
    if (type == fs::file_type::regular) return std::optional<fs::path>(sidecar);
  }
  return std::optional<fs::path>();
}

Result<std::unique_ptr<VolumeSource>> OpenRawWithSidecar(const fs::path& sidecar,
                                                         const OpenOptions& options) {
  if (!options.parse_raw_sidecar) {
    return UnsupportedError(sidecar.string() + ": JSON raw sidecars are not enabled");
  }
  OCTO_ASSIGN_OR_RETURN(const std::string text,
                        options.file_gate.ReadSmallFile(sidecar, kMaxRawSidecarBytes));
  OCTO_ASSIGN_OR_RETURN(RawLayout layout, options.parse_raw_sidecar(text, sidecar));
  auto source = OpenRawVolume(layout, options);
  // The raw file's error names the raw file; the user named the sidecar: say both.
  if (!source.ok()) return source.status().WithContext(sidecar.string());
  return source;
}

Result<std::unique_ptr<VolumeSource>> OpenAny(const fs::path& path, const OpenOptions& options) {
  const FileGate& gate = options.file_gate;
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(path));
  if (type == fs::file_type::not_found) {
    return NotFoundError(path.string() + ": no such file or folder");
  }
  const bool folder = type == fs::file_type::directory;
  const std::string name = path.filename().string();
  OCTO_ASSIGN_OR_RETURN(const bool zarr, LooksLikeZarr(path, gate));
  if (zarr || (folder && EndsWithIgnoreCase(name, ".zarr"))) return OpenOmeZarr(path, options);
  if (folder) return OpenSliceFolder(path, options);
  if (type != fs::file_type::regular) {
    return UnsupportedError(path.string() + ": not a regular file");
  }

  // Choose by name where the name is unambiguous, else by content.
  if (EndsWithIgnoreCase(name, ".ims") || HasHdf5Signature(path, gate)) {
    return OpenImaris(path, options);
  }
  if (EndsWithIgnoreCase(name, ".companion.ome") || EndsWithIgnoreCase(name, ".ome") ||
      EndsWithIgnoreCase(name, ".ome.xml")) {
    return OpenOmeTiff(path, options);
  }
  if (EndsWithIgnoreCase(name, ".vvd")) {
    OCTO_ASSIGN_OR_RETURN(RawLayout layout, ReadVoreenVvd(path, gate));
    auto source = OpenRawVolume(layout, options);
    if (!source.ok()) return source.status().WithContext(path.string());
    return source;
  }
  if (EndsWithIgnoreCase(name, ".json")) return OpenRawWithSidecar(path, options);
  if (HasTiffSignature(path, gate)) {
    // Index the file once; an OME-XML root element in the first IFD makes it an OME-TIFF (whose
    // reader may need further files), anything else is a plain/ImageJ/ScanImage stack.
    TiffFile::Limits limits;
    limits.max_plane_bytes = options.max_plane_bytes;
    OCTO_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file, TiffFile::Open(path, limits, gate));
    if (file->ifd_count() > 0 && LooksLikeOmeXml(file->ifd(0).description)) {
      return OpenOmeTiff(path, options);
    }
    return OpenTiffStack(std::move(file), options);
  }
  OCTO_ASSIGN_OR_RETURN(const std::optional<fs::path> sidecar, FindRawSidecar(path, gate));
  if (sidecar) return OpenRawWithSidecar(*sidecar, options);
  OCTO_ASSIGN_OR_RETURN(const fs::path real, gate.Resolve(path));
  std::error_code ec;
  if (fs::file_size(real, ec) == 0 && !ec) return CorruptError(path.string() + ": empty file");
  return UnsupportedError(path.string() +
                          ": not a TIFF/OME-TIFF, and no .json or .vvd sidecar describes it");
}

// A source whose reads may meet a file outside its folder (a slice replaced by a link since it
// was opened): such a read fails with the dataset's one refusal, as the open would have.
class ConfinedSource final : public VolumeSource {
 public:
  ConfinedSource(std::unique_ptr<VolumeSource> source, fs::path dataset)
      : source_(std::move(source)), dataset_(std::move(dataset)) {}
  const volume::VolumeInfo& info() const override { return source_->info(); }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    return OutsideFolderErrorOf(source_->ReadSlab(channel, z0, nz, out), dataset_);
  }
  std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const override {
    return source_->FindStoredPlane(channel, z);
  }
  int64_t PreferredSlabPlanes() const override { return source_->PreferredSlabPlanes(); }

 private:
  const std::unique_ptr<VolumeSource> source_;
  const fs::path dataset_;
};

}  // namespace

Result<std::unique_ptr<VolumeSource>> OpenVolume(const fs::path& path, const OpenOptions& options) {
  Result<std::unique_ptr<VolumeSource>> opened = OpenAny(path, options);
  // A refusal says nothing but that: not which reference, nor whether what it names exists.
  if (!opened.ok()) return OutsideFolderErrorOf(opened.status(), path);
  std::unique_ptr<VolumeSource> source = std::move(*opened);
  // Single-resolution formats ignore OpenOptions::level: asking them for a coarser one is an error.
  const volume::VolumeInfo& info = source->info();
  if (options.level != info.level) {
    return OutOfRangeError(path.string() + ": resolution level " + std::to_string(options.level) +
                           " asked for, the file has " + std::to_string(info.level_count));
  }
  if (options.on_warning) {
    for (const std::string& warning : info.warnings) options.on_warning(warning);
  }
  if (options.file_gate.confined()) {
    return std::unique_ptr<VolumeSource>(std::make_unique<ConfinedSource>(std::move(source), path));
  }
  return source;
}

}  // namespace octoscope::io
