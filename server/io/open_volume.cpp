#include "io/open_volume.h"

#include <system_error>

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
std::optional<fs::path> FindRawSidecar(const fs::path& raw) {
  std::error_code ec;
  fs::path with_suffix = raw;
  with_suffix += ".json";
  if (fs::is_regular_file(with_suffix, ec)) return with_suffix;
  fs::path replaced = raw;
  replaced.replace_extension(".json");
  if (fs::is_regular_file(replaced, ec)) return replaced;
  return std::nullopt;
}

Result<std::unique_ptr<VolumeSource>> OpenRawWithSidecar(const fs::path& sidecar,
                                                         const OpenOptions& options) {
  if (!options.load_raw_sidecar) {
    return UnsupportedError(sidecar.string() + ": JSON raw sidecars are not enabled");
  }
  OCTO_ASSIGN_OR_RETURN(RawLayout layout, options.load_raw_sidecar(sidecar));
  auto source = OpenRawVolume(layout, options);
  // The raw file's error names the raw file; the user named the sidecar: say both.
  if (!source.ok()) return source.status().WithContext(sidecar.string());
  return source;
}

Result<std::unique_ptr<VolumeSource>> OpenAny(const fs::path& path, const OpenOptions& options) {
  std::error_code ec;
  fs::file_status status = fs::status(path, ec);
  if (ec || !fs::exists(status)) return NotFoundError(path.string() + ": no such file or folder");
  const std::string name = path.filename().string();
  if (LooksLikeZarr(path) || (fs::is_directory(status) && EndsWithIgnoreCase(name, ".zarr"))) {
    return OpenOmeZarr(path, options);
  }
  if (fs::is_directory(status)) return OpenSliceFolder(path, options);
  if (!fs::is_regular_file(status)) return UnsupportedError(path.string() + ": not a regular file");

  // Choose by name where the name is unambiguous, else by content.
  if (EndsWithIgnoreCase(name, ".ims") || HasHdf5Signature(path)) return OpenImaris(path, options);
  if (EndsWithIgnoreCase(name, ".companion.ome") || EndsWithIgnoreCase(name, ".ome") ||
      EndsWithIgnoreCase(name, ".ome.xml")) {
    return OpenOmeTiff(path, options);
  }
  if (EndsWithIgnoreCase(name, ".vvd")) {
    OCTO_ASSIGN_OR_RETURN(RawLayout layout, ReadVoreenVvd(path));
    auto source = OpenRawVolume(layout, options);
    if (!source.ok()) return source.status().WithContext(path.string());
    return source;
  }
  if (EndsWithIgnoreCase(name, ".json")) return OpenRawWithSidecar(path, options);
  if (HasTiffSignature(path)) {
    // Index the file once; an OME-XML root element in the first IFD makes it an OME-TIFF (whose
    // reader may need further files), anything else is a plain/ImageJ/ScanImage stack.
    TiffFile::Limits limits;
    limits.max_plane_bytes = options.max_plane_bytes;
    OCTO_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file, TiffFile::Open(path, limits));
    if (file->ifd_count() > 0 && LooksLikeOmeXml(file->ifd(0).description)) {
      return OpenOmeTiff(path, options);
    }
    return OpenTiffStack(std::move(file), options);
  }
  if (auto sidecar = FindRawSidecar(path)) return OpenRawWithSidecar(*sidecar, options);
  if (fs::file_size(path, ec) == 0 && !ec) return CorruptError(path.string() + ": empty file");
  return UnsupportedError(path.string() +
                          ": not a TIFF/OME-TIFF, and no .json or .vvd sidecar describes it");
}

}  // namespace

Result<std::unique_ptr<VolumeSource>> OpenVolume(const fs::path& path, const OpenOptions& options) {
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<VolumeSource> source, OpenAny(path, options));
  // Single-resolution formats ignore OpenOptions::level: asking them for a coarser one is an error.
  const volume::VolumeInfo& info = source->info();
  if (options.level != info.level) {
    return OutOfRangeError(path.string() + ": resolution level " + std::to_string(options.level) +
                           " asked for, the file has " + std::to_string(info.level_count));
  }
  if (options.on_warning) {
    for (const std::string& warning : info.warnings) options.on_warning(warning);
  }
  return source;
}

}  // namespace octoscope::io
