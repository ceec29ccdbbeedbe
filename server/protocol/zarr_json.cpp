#include "protocol/zarr_json.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>

#include "protocol/json_parse.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;

std::string TypeOf(const json& j) { return std::string(j.type_name()); }

// "where" names the key path in messages: `"chunks"[2]`, `codecs[1].configuration.cname`.
Status Bad(const std::string& where, const std::string& problem) {
  return CorruptError(where + " " + problem);
}

Result<json> ParseDocument(std::string_view text) {
  OCTO_ASSIGN_OR_RETURN(json doc, ParseJsonLimited(text, kMaxZarrJsonDepth));
  if (!doc.is_object()) return CorruptError("must be a JSON object, got " + TypeOf(doc));
  return doc;
}

const json* Find(const json& object, const char* key) {
  auto it = object.find(key);
  return it == object.end() ? nullptr : &*it;
}

Result<int64_t> Integer(const json& j, const std::string& where, int64_t lo) {
  if (!j.is_number_integer() ||
      (j.is_number_unsigned() && j.get<uint64_t>() > static_cast<uint64_t>(INT64_MAX))) {
    return Bad(where, "must be an integer, got " + TypeOf(j));
  }
  const int64_t v = j.get<int64_t>();
  if (v < lo) return Bad(where, "is " + std::to_string(v) + ", must be >= " + std::to_string(lo));
  return v;
}

Result<std::vector<int64_t>> IntegerList(const json& j, const std::string& where, int64_t lo) {
  if (!j.is_array()) return Bad(where, "must be an array of integers, got " + TypeOf(j));
  std::vector<int64_t> out;
  for (size_t i = 0; i < j.size(); ++i) {
    OCTO_ASSIGN_OR_RETURN(int64_t v, Integer(j[i], where + "[" + std::to_string(i) + "]", lo));
    out.push_back(v);
  }
  return out;
}

Result<std::vector<double>> NumberList(const json& j, const std::string& where) {
  if (!j.is_array()) return Bad(where, "must be an array of numbers, got " + TypeOf(j));
  std::vector<double> out;
  for (size_t i = 0; i < j.size(); ++i) {
    if (!j[i].is_number()) {
      return Bad(where + "[" + std::to_string(i) + "]", "must be a number, got " + TypeOf(j[i]));
    }
    out.push_back(j[i].get<double>());
  }
  return out;
}

Result<std::string> String(const json& j, const std::string& where) {
  if (!j.is_string()) return Bad(where, "must be a string, got " + TypeOf(j));
  return j.get<std::string>();
}

// A v2 dtype ("<u2", ">f8", "|u1") or v3 data_type ("uint16").
struct SampleType {
  volume::DataType type;
  bool big_endian = false;
};

Result<SampleType> V2Dtype(const json& j) {
  if (j.is_array()) return UnsupportedError("\"dtype\": structured dtypes are not supported");
  OCTO_ASSIGN_OR_RETURN(std::string s, String(j, "\"dtype\""));
  const std::string quoted = "\"dtype\" \"" + Printable(s) + "\"";
  if (s.size() < 3 || (s[0] != '<' && s[0] != '>' && s[0] != '|')) {
    return CorruptError(quoted + " is not a numpy type string such as \"<u2\"");
  }
  const std::string kind = s.substr(1);
  static const struct {
    const char* code;
    volume::DataType type;
  } kTypes[] = {{"u1", volume::DataType::kUint8},   {"i1", volume::DataType::kInt8},
                {"u2", volume::DataType::kUint16},  {"i2", volume::DataType::kInt16},
                {"u4", volume::DataType::kUint32},  {"i4", volume::DataType::kInt32},
                {"f4", volume::DataType::kFloat32}, {"f8", volume::DataType::kFloat64}};
  for (const auto& t : kTypes) {
    if (kind == t.code) {
      if (s[0] == '|' && volume::BytesPerSample(t.type) > 1) {
        return CorruptError(quoted + ": multi-byte types need a byte order ('<' or '>')");
      }
      return SampleType{t.type, s[0] == '>'};
    }
  }
  return UnsupportedError(quoted +
                          " (supported: u1, i1, u2, i2, u4, i4, f4, f8 in either byte "
                          "order)");
}

Result<volume::DataType> V3DataType(const json& j) {
  OCTO_ASSIGN_OR_RETURN(std::string s, String(j, "\"data_type\""));
  if (std::optional<volume::DataType> t = volume::DataTypeFromNumpyName(s)) return *t;
  return UnsupportedError("\"data_type\" \"" + Printable(s) +
                          "\" (supported: uint8, int8, uint16, int16, uint32, int32, float32, "
                          "float64)");
}

// A fill value: number, null, "NaN", "Infinity", "-Infinity", or (v3) a hex bit pattern
// "0x7fc00000" of a float type.
Result<std::optional<double>> FillValue(const json& j, volume::DataType type) {
  const std::string where = "\"fill_value\"";
  if (j.is_null()) return std::optional<double>();
  if (j.is_boolean()) return std::optional<double>(j.get<bool>() ? 1.0 : 0.0);
  if (j.is_number()) {
    if (!volume::IsFloat(type) && !j.is_number_integer()) {
      return Bad(where, "must be an integer for an integer type");
    }
    return std::optional<double>(j.get<double>());
  }
  if (j.is_string()) {
    const std::string s = j.get<std::string>();
    if (volume::IsFloat(type)) {
      if (s == "NaN") return std::optional<double>(std::nan(""));
      if (s == "Infinity") return std::optional<double>(std::numeric_limits<double>::infinity());
      if (s == "-Infinity") return std::optional<double>(-std::numeric_limits<double>::infinity());
      const size_t digits = 2 * volume::BytesPerSample(type);
      if (s.size() == 2 + digits && s[0] == '0' && s[1] == 'x' &&
          s.find_first_not_of("0123456789abcdefABCDEF", 2) == std::string::npos) {
        const uint64_t bits = std::stoull(s.substr(2), nullptr, 16);
        if (type == volume::DataType::kFloat32) {
          const uint32_t b32 = static_cast<uint32_t>(bits);
          float f;
          std::memcpy(&f, &b32, 4);
          return std::optional<double>(f);
        }
        double d;
        std::memcpy(&d, &bits, 8);
        return std::optional<double>(d);
      }
    }
    return Bad(where, "\"" + Printable(s) + "\" is not a fill value of this type");
  }
  return Bad(where, "must be a number, null or a string, got " + TypeOf(j));
}

// numcodecs / Zarr v3 compressor names.
Result<io::ChunkCodec> CompressorNamed(const std::string& id, const std::string& where) {
  if (id == "blosc") return io::ChunkCodec::kBlosc;
  if (id == "zstd") return io::ChunkCodec::kZstd;
  if (id == "zlib") return io::ChunkCodec::kZlib;
  if (id == "gzip") return io::ChunkCodec::kGzip;
  if (id == "lz4") return io::ChunkCodec::kLz4;
  if (id == "crc32c") return io::ChunkCodec::kCrc32c;
  return UnsupportedError(
      where + " \"" + Printable(id) + "\" (supported: blosc, zstd, zlib, gzip, lz4" +
      std::string(where.find("codec") != std::string::npos ? ", crc32c" : "") + ")");
}

Result<io::ZarrArrayMetadata> ParseV2Array(const json& doc) {
  io::ZarrArrayMetadata m;
  m.zarr_format = 2;
  for (const char* key : {"shape", "chunks", "dtype"}) {
    if (!Find(doc, key)) return CorruptError(std::string("missing required key \"") + key + "\"");
  }
  OCTO_ASSIGN_OR_RETURN(m.shape, IntegerList(doc["shape"], "\"shape\"", 0));
  OCTO_ASSIGN_OR_RETURN(m.chunks, IntegerList(doc["chunks"], "\"chunks\"", 1));
  OCTO_ASSIGN_OR_RETURN(SampleType t, V2Dtype(doc["dtype"]));
  m.dtype = t.type;
  m.encoding.big_endian = t.big_endian;
  if (const json* f = Find(doc, "fill_value")) {
    OCTO_ASSIGN_OR_RETURN(m.fill_value, FillValue(*f, m.dtype));
  }
  if (const json* o = Find(doc, "order")) {
    OCTO_ASSIGN_OR_RETURN(std::string order, String(*o, "\"order\""));
    if (order == "F") {
      for (size_t d = m.shape.size(); d-- > 0;) m.encoding.order.push_back(static_cast<int>(d));
    } else if (order != "C") {
      return Bad("\"order\"", "must be \"C\" or \"F\", got \"" + Printable(order) + "\"");
    }
  }
  if (const json* f = Find(doc, "filters"); f && !f->is_null()) {
    if (!f->is_array()) return Bad("\"filters\"", "must be null or an array");
    if (!f->empty()) {
      std::string ids;
      for (const json& filter : *f) {
        const json* id = filter.is_object() ? Find(filter, "id") : nullptr;
        ids += (ids.empty() ? "" : ", ") +
               (id && id->is_string() ? Printable(id->get<std::string>()) : std::string("?"));
      }
      return UnsupportedError("\"filters\" [" + ids + "]: Zarr filters are not supported");
    }
  }
  if (const json* c = Find(doc, "compressor"); c && !c->is_null()) {
    if (!c->is_object()) return Bad("\"compressor\"", "must be null or an object");
    const json* id = Find(*c, "id");
    if (!id) return Bad("\"compressor\"", "has no \"id\"");
    OCTO_ASSIGN_OR_RETURN(std::string name, String(*id, "\"compressor\".id"));
    OCTO_ASSIGN_OR_RETURN(io::ChunkCodec codec, CompressorNamed(name, "\"compressor\""));
    if (codec == io::ChunkCodec::kCrc32c) {
      return UnsupportedError("\"compressor\" \"crc32c\" is a Zarr v3 codec");
    }
    m.encoding.codecs.push_back(codec);
  }
  if (const json* s = Find(doc, "dimension_separator"); s && !s->is_null()) {
    OCTO_ASSIGN_OR_RETURN(std::string sep, String(*s, "\"dimension_separator\""));
    if (sep != "." && sep != "/") {
      return Bad("\"dimension_separator\"",
                 "must be \".\" or \"/\", got \"" + Printable(sep) + "\"");
    }
    m.separator = sep[0];
  }
  return m;
}

// v3: the "name"/"configuration" object of a codec, chunk grid or key encoding.
Status NamedConfig(const json& j, const std::string& where, std::string& name,
                   const json*& config) {
  if (j.is_string()) {  // Short form: just the name.
    name = j.get<std::string>();
    config = nullptr;
    return Status::Ok();
  }
  if (!j.is_object()) return Bad(where, "must be an object, got " + TypeOf(j));
  const json* n = Find(j, "name");
  if (!n) return Bad(where, "has no \"name\"");
  OCTO_ASSIGN_OR_RETURN(name, String(*n, where + ".name"));
  config = Find(j, "configuration");
  if (config && !config->is_object()) return Bad(where + ".configuration", "must be an object");
  return Status::Ok();
}

// A v3 codec list into `encoding` (+ `sharding` when allowed).
Status ParseCodecs(const json& list, const std::string& where, size_t dims,
                   io::ZarrChunkEncoding& encoding, std::optional<io::ZarrSharding>* sharding) {
  if (!list.is_array()) return Bad(where, "must be an array of codecs");
  bool have_bytes = false;
  for (size_t i = 0; i < list.size(); ++i) {
    const std::string at = where + "[" + std::to_string(i) + "]";
    std::string name;
    const json* config = nullptr;
    OCTO_RETURN_IF_ERROR(NamedConfig(list[i], at, name, config));
    if (name == "transpose") {
      if (have_bytes) return Bad(at, "transpose must come before the bytes codec");
      if (!encoding.order.empty()) return UnsupportedError(at + ": several transpose codecs");
      const json* order = config ? Find(*config, "order") : nullptr;
      if (!order) return Bad(at, "has no configuration.order");
      if (order->is_string()) {
        // Early v3 drafts: "C" or "F".
        const std::string o = order->get<std::string>();
        if (o == "F") {
          for (size_t d = dims; d-- > 0;) encoding.order.push_back(static_cast<int>(d));
        } else if (o != "C") {
          return Bad(at + ".configuration.order", "must be a permutation");
        }
      } else {
        OCTO_ASSIGN_OR_RETURN(std::vector<int64_t> perm,
                              IntegerList(*order, at + ".configuration.order", 0));
        for (int64_t p : perm) {
          if (p >= static_cast<int64_t>(dims)) return Bad(at, "order out of range");
          encoding.order.push_back(static_cast<int>(p));
        }
      }
    } else if (name == "bytes" || name == "endian") {
      if (have_bytes) return Bad(at, "a second array-to-bytes codec");
      have_bytes = true;
      if (const json* e = config ? Find(*config, "endian") : nullptr) {
        OCTO_ASSIGN_OR_RETURN(std::string endian, String(*e, at + ".configuration.endian"));
        if (endian != "little" && endian != "big") {
          return Bad(at + ".configuration.endian", "must be \"little\" or \"big\"");
        }
        encoding.big_endian = endian == "big";
      }
    } else if (name == "sharding_indexed") {
      if (!sharding) return UnsupportedError(at + ": nested sharding is not supported");
      if (have_bytes || i != 0 || list.size() != 1) {
        return UnsupportedError(at + ": sharding_indexed must be the array's only codec");
      }
      have_bytes = true;
      if (!config) return Bad(at, "has no configuration");
      io::ZarrSharding s;
      const json* shape = Find(*config, "chunk_shape");
      if (!shape) return Bad(at, "has no configuration.chunk_shape");
      OCTO_ASSIGN_OR_RETURN(s.inner_chunks,
                            IntegerList(*shape, at + ".configuration.chunk_shape", 1));
      const json* inner = Find(*config, "codecs");
      if (!inner) return Bad(at, "has no configuration.codecs");
      OCTO_RETURN_IF_ERROR(
          ParseCodecs(*inner, at + ".configuration.codecs", dims, s.inner, nullptr));
      if (const json* loc = Find(*config, "index_location")) {
        OCTO_ASSIGN_OR_RETURN(std::string l, String(*loc, at + ".configuration.index_location"));
        if (l != "start" && l != "end") {
          return Bad(at + ".configuration.index_location", "must be \"start\" or \"end\"");
        }
        s.index_at_end = l == "end";
      }
      if (const json* index = Find(*config, "index_codecs")) {
        io::ZarrChunkEncoding ie;
        OCTO_RETURN_IF_ERROR(
            ParseCodecs(*index, at + ".configuration.index_codecs", 1, ie, nullptr));
        const bool crc_only = ie.codecs.size() == 1 && ie.codecs[0] == io::ChunkCodec::kCrc32c;
        if (ie.big_endian || !ie.order.empty() || (!ie.codecs.empty() && !crc_only)) {
          return UnsupportedError(at +
                                  ": index_codecs other than [bytes little] or [bytes little, "
                                  "crc32c]");
        }
        s.index_crc32c = crc_only;
      }
      *sharding = std::move(s);
    } else {
      OCTO_ASSIGN_OR_RETURN(io::ChunkCodec codec, CompressorNamed(name, at + " codec"));
      if (!have_bytes)
        return Bad(at, "bytes-to-bytes codec \"" + name + "\" before the bytes codec");
      if (sharding && *sharding) {
        return UnsupportedError(at + ": codecs after sharding_indexed are not supported");
      }
      encoding.codecs.push_back(codec);
    }
  }
  if (!have_bytes) return Bad(where, "has no array-to-bytes codec (\"bytes\")");
  return Status::Ok();
}

Result<io::ZarrArrayMetadata> ParseV3Array(const json& doc) {
  io::ZarrArrayMetadata m;
  m.zarr_format = 3;
  for (const char* key : {"shape", "data_type", "chunk_grid", "codecs"}) {
    if (!Find(doc, key)) return CorruptError(std::string("missing required key \"") + key + "\"");
  }
  OCTO_ASSIGN_OR_RETURN(m.shape, IntegerList(doc["shape"], "\"shape\"", 0));
  OCTO_ASSIGN_OR_RETURN(m.dtype, V3DataType(doc["data_type"]));
  {
    std::string name;
    const json* config = nullptr;
    OCTO_RETURN_IF_ERROR(NamedConfig(doc["chunk_grid"], "\"chunk_grid\"", name, config));
    if (name != "regular") {
      return UnsupportedError("\"chunk_grid\" \"" + Printable(name) + "\" (only \"regular\")");
    }
    const json* shape = config ? Find(*config, "chunk_shape") : nullptr;
    if (!shape) return Bad("\"chunk_grid\"", "has no configuration.chunk_shape");
    OCTO_ASSIGN_OR_RETURN(m.chunks, IntegerList(*shape, "\"chunk_grid\".chunk_shape", 1));
  }
  m.key_prefix = "c";
  m.separator = '/';
  if (const json* enc = Find(doc, "chunk_key_encoding")) {
    std::string name;
    const json* config = nullptr;
    OCTO_RETURN_IF_ERROR(NamedConfig(*enc, "\"chunk_key_encoding\"", name, config));
    if (name == "v2") {
      m.key_prefix.clear();
      m.separator = '.';
    } else if (name != "default") {
      return UnsupportedError("\"chunk_key_encoding\" \"" + Printable(name) + "\"");
    }
    if (const json* sep = config ? Find(*config, "separator") : nullptr) {
      OCTO_ASSIGN_OR_RETURN(std::string s, String(*sep, "\"chunk_key_encoding\".separator"));
      if (s != "." && s != "/") return Bad("\"chunk_key_encoding\".separator", "must be . or /");
      m.separator = s[0];
    }
  }
  if (const json* f = Find(doc, "fill_value")) {
    OCTO_ASSIGN_OR_RETURN(m.fill_value, FillValue(*f, m.dtype));
  }
  OCTO_RETURN_IF_ERROR(
      ParseCodecs(doc["codecs"], "\"codecs\"", m.shape.size(), m.encoding, &m.sharding));
  if (const json* names = Find(doc, "dimension_names"); names && !names->is_null()) {
    if (!names->is_array()) return Bad("\"dimension_names\"", "must be an array");
    for (const json& n : *names)
      m.dimension_names.push_back(n.is_string() ? n.get<std::string>() : "");
  }
  if (const json* st = Find(doc, "storage_transformers"); st && !(st->is_array() && st->empty())) {
    return UnsupportedError("\"storage_transformers\" are not supported");
  }
  // Extensions Octoscope does not know must be marked optional.
  static const char* kKnown[] = {
      "zarr_format",         "node_type",  "shape",  "data_type",  "chunk_grid",
      "chunk_key_encoding",  "fill_value", "codecs", "attributes", "dimension_names",
      "storage_transformers"};
  for (const auto& [key, value] : doc.items()) {
    bool known = false;
    for (const char* k : kKnown) known = known || key == k;
    if (known) continue;
    const json* must = value.is_object() ? Find(value, "must_understand") : nullptr;
    if (!(must && must->is_boolean() && !must->get<bool>())) {
      return UnsupportedError("extension \"" + Printable(key) + "\" must be understood");
    }
  }
  return m;
}

// "coordinateTransformations": [{"type": "scale", "scale": [...]}, {"type": "translation", ...}].
// A transformation given by "path" (a separate array) leaves the values unknown.
Status ParseTransforms(const json& list, const std::string& where, io::NgffTransform& out) {
  if (!list.is_array()) return Bad(where, "must be an array");
  for (size_t i = 0; i < list.size(); ++i) {
    const std::string at = where + "[" + std::to_string(i) + "]";
    const json& t = list[i];
    if (!t.is_object()) return Bad(at, "must be an object");
    const json* type = Find(t, "type");
    if (!type) return Bad(at, "has no \"type\"");
    OCTO_ASSIGN_OR_RETURN(std::string kind, String(*type, at + ".type"));
    if (kind == "identity") continue;
    if (kind != "scale" && kind != "translation") {
      return UnsupportedError(at + ": transformation \"" + Printable(kind) + "\"");
    }
    const json* values = Find(t, kind.c_str());
    if (!values) continue;  // Given by "path": unknown to us.
    OCTO_ASSIGN_OR_RETURN(std::vector<double> v, NumberList(*values, at + "." + kind));
    std::vector<double>& target = kind == "scale" ? out.scale : out.translation;
    if (target.empty()) {
      target = std::move(v);
    } else if (target.size() == v.size()) {
      for (size_t k = 0; k < v.size(); ++k) {
        if (kind == "scale") {
          target[k] *= v[k];
        } else {
          target[k] += v[k];
        }
      }
    } else {
      return Bad(at, "has " + std::to_string(v.size()) + " values, an earlier one " +
                         std::to_string(target.size()));
    }
  }
  return Status::Ok();
}

Result<io::NgffMultiscale> ParseMultiscale(const json& j, const std::string& where) {
  if (!j.is_object()) return Bad(where, "must be an object");
  io::NgffMultiscale m;
  if (const json* v = Find(j, "version"); v && v->is_string()) m.version = v->get<std::string>();
  if (const json* n = Find(j, "name"); n && n->is_string()) m.name = n->get<std::string>();
  if (const json* axes = Find(j, "axes")) {
    if (!axes->is_array()) return Bad(where + ".axes", "must be an array");
    for (size_t i = 0; i < axes->size(); ++i) {
      const json& a = (*axes)[i];
      const std::string at = where + ".axes[" + std::to_string(i) + "]";
      io::NgffAxis axis;
      if (a.is_string()) {  // NGFF 0.3: names only.
        axis.name = a.get<std::string>();
      } else if (a.is_object()) {
        const json* name = Find(a, "name");
        if (!name) return Bad(at, "has no \"name\"");
        OCTO_ASSIGN_OR_RETURN(axis.name, String(*name, at + ".name"));
        if (const json* t = Find(a, "type"); t && t->is_string()) axis.type = t->get<std::string>();
        if (const json* u = Find(a, "unit"); u && u->is_string()) axis.unit = u->get<std::string>();
      } else {
        return Bad(at, "must be an object or a string");
      }
      m.axes.push_back(std::move(axis));
    }
  }
  const json* datasets = Find(j, "datasets");
  if (!datasets) return Bad(where, "has no \"datasets\"");
  if (!datasets->is_array()) return Bad(where + ".datasets", "must be an array");
  for (size_t i = 0; i < datasets->size(); ++i) {
    const json& d = (*datasets)[i];
    const std::string at = where + ".datasets[" + std::to_string(i) + "]";
    if (!d.is_object()) return Bad(at, "must be an object");
    const json* path = Find(d, "path");
    if (!path) return Bad(at, "has no \"path\"");
    io::NgffDataset dataset;
    OCTO_ASSIGN_OR_RETURN(dataset.path, String(*path, at + ".path"));
    if (const json* t = Find(d, "coordinateTransformations")) {
      OCTO_RETURN_IF_ERROR(
          ParseTransforms(*t, at + ".coordinateTransformations", dataset.transform));
    }
    m.datasets.push_back(std::move(dataset));
  }
  if (const json* t = Find(j, "coordinateTransformations")) {
    OCTO_RETURN_IF_ERROR(ParseTransforms(*t, where + ".coordinateTransformations", m.transform));
  }
  return m;
}

// "RRGGBB" (or "RRGGBBAA"); nullopt when malformed (a colour is a display hint).
std::optional<volume::Rgba> OmeroColor(const json& j) {
  if (!j.is_string()) return std::nullopt;
  const std::string s = j.get<std::string>();
  if ((s.size() != 6 && s.size() != 8) ||
      s.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos) {
    return std::nullopt;
  }
  const unsigned long v = std::stoul(s, nullptr, 16);
  volume::Rgba c;
  const int shift = s.size() == 8 ? 8 : 0;
  c.r = static_cast<uint8_t>(v >> (16 + shift));
  c.g = static_cast<uint8_t>(v >> (8 + shift));
  c.b = static_cast<uint8_t>(v >> shift);
  if (shift) c.a = static_cast<uint8_t>(v);
  return c;
}

std::optional<double> FiniteNumber(const json& object, const char* key) {
  const json* v = Find(object, key);
  if (!v || !v->is_number()) return std::nullopt;
  const double d = v->get<double>();
  return std::isfinite(d) ? std::optional<double>(d) : std::nullopt;
}

// "omero": {"channels": [{"label", "color", "window": {"start", "end", "min", "max"}}]}. The
// channel list must be well formed; malformed colours and windows are ignored (display hints).
Status ParseOmero(const json& omero, io::NgffAttributes& out) {
  if (!omero.is_object()) return Bad("\"omero\"", "must be an object");
  const json* channels = Find(omero, "channels");
  if (!channels) return Status::Ok();
  if (!channels->is_array()) return Bad("\"omero\".channels", "must be an array");
  out.has_omero = true;
  for (const json& c : *channels) {
    io::OmeroChannel channel;
    if (c.is_object()) {
      if (const json* l = Find(c, "label"); l && l->is_string())
        channel.label = l->get<std::string>();
      if (const json* col = Find(c, "color")) channel.color = OmeroColor(*col);
      if (const json* w = Find(c, "window"); w && w->is_object()) {
        std::optional<double> start = FiniteNumber(*w, "start"), end = FiniteNumber(*w, "end");
        if (start && end) {
          channel.window =
              volume::DisplayWindow{*start, *end, FiniteNumber(*w, "min"), FiniteNumber(*w, "max")};
        }
      }
    }
    out.omero_channels.push_back(std::move(channel));
  }
  return Status::Ok();
}

// The NGFF attributes object (v2 .zattrs itself; v3 attributes, or attributes.ome for 0.5).
Status ParseNgff(const json& attrs, io::NgffAttributes& out) {
  if (!attrs.is_object()) return Bad("attributes", "must be an object");
  std::string version;
  if (const json* v = Find(attrs, "version"); v && v->is_string()) version = v->get<std::string>();
  if (const json* ms = Find(attrs, "multiscales")) {
    if (!ms->is_array()) return Bad("\"multiscales\"", "must be an array");
    for (size_t i = 0; i < ms->size(); ++i) {
      OCTO_ASSIGN_OR_RETURN(
          io::NgffMultiscale m,
          ParseMultiscale((*ms)[i], "\"multiscales\"[" + std::to_string(i) + "]"));
      if (m.version.empty()) m.version = version;
      out.multiscales.push_back(std::move(m));
    }
  }
  if (const json* omero = Find(attrs, "omero")) OCTO_RETURN_IF_ERROR(ParseOmero(*omero, out));
  if (const json* layout = Find(attrs, "bioformats2raw.layout")) {
    OCTO_ASSIGN_OR_RETURN(out.bioformats2raw_layout,
                          Integer(*layout, "\"bioformats2raw.layout\"", 0));
  }
  out.is_plate = Find(attrs, "plate") != nullptr || Find(attrs, "well") != nullptr;
  return Status::Ok();
}

Result<io::NgffAttributes> ParseAttributes(const json& doc) {
  io::NgffAttributes out;
  const json* format = Find(doc, "zarr_format");
  if (format && format->is_number_integer() && format->get<int64_t>() == 3) {
    // A v3 zarr.json: a group or an array, attributes inside.
    const json* type = Find(doc, "node_type");
    if (!type) return CorruptError("zarr.json has no \"node_type\"");
    OCTO_ASSIGN_OR_RETURN(out.node_type, String(*type, "\"node_type\""));
    if (out.node_type != "group" && out.node_type != "array") {
      return Bad("\"node_type\"", "must be \"group\" or \"array\"");
    }
    const json* attrs = Find(doc, "attributes");
    if (!attrs) return out;
    if (!attrs->is_object()) return Bad("\"attributes\"", "must be an object");
    const json* ome = Find(*attrs, "ome");
    OCTO_RETURN_IF_ERROR(ParseNgff(ome ? *ome : *attrs, out));
    return out;
  }
  OCTO_RETURN_IF_ERROR(ParseNgff(doc, out));
  return out;
}

// Runs `parse` on the document, turning any exception (a bug, or std::bad_alloc) into a Status.
template <typename T, typename F>
Result<T> Guarded(std::string_view text, F parse) {
  try {
    OCTO_ASSIGN_OR_RETURN(json doc, ParseDocument(text));
    return parse(doc);
  } catch (const std::bad_alloc&) {
    return ResourceExhaustedError("out of memory parsing Zarr JSON");
  } catch (const std::exception& e) {
    return InternalError(std::string("parsing Zarr JSON: ") + e.what());
  }
}

}  // namespace

Result<io::ZarrArrayMetadata> ParseZarrArrayJson(std::string_view json_text) {
  return Guarded<io::ZarrArrayMetadata>(
      json_text, [](const json& doc) -> Result<io::ZarrArrayMetadata> {
        const json* format = Find(doc, "zarr_format");
        if (!format) return CorruptError("missing required key \"zarr_format\"");
        OCTO_ASSIGN_OR_RETURN(int64_t version, Integer(*format, "\"zarr_format\"", 0));
        if (version == 2) return ParseV2Array(doc);
        if (version == 3) {
          const json* type = Find(doc, "node_type");
          if (!type || !type->is_string() || type->get<std::string>() != "array") {
            return CorruptError("zarr.json is not an array (\"node_type\" must be \"array\")");
          }
          return ParseV3Array(doc);
        }
        return UnsupportedError("\"zarr_format\" " + std::to_string(version) +
                                " (supported: 2, 3)");
      });
}

Result<io::NgffAttributes> ParseZarrAttributesJson(std::string_view json_text) {
  return Guarded<io::NgffAttributes>(json_text, ParseAttributes);
}

io::ZarrJsonParsers MakeZarrJsonParsers() {
  io::ZarrJsonParsers parsers;
  parsers.array = ParseZarrArrayJson;
  parsers.attributes = ParseZarrAttributesJson;
  return parsers;
}

}  // namespace octoscope::protocol
