// Zarr JSON: .zarray (v2), array zarr.json (v3: codecs, sharding, key encodings, fill values) and
// group attributes (NGFF 0.3 – 0.5, omero, bioformats2raw, plates) into typed metadata; errors
// name the key; unsupported features are named; hostile documents never throw.
#include "protocol/zarr_json.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace octoscope::protocol {
namespace {

using io::ChunkCodec;

TEST(ZarrJson, V2ArrayAllFields) {
  auto m = ParseZarrArrayJson(R"({"zarr_format": 2, "shape": [3, 150, 158, 96],
      "chunks": [3, 128, 128, 96], "dtype": ">f8", "fill_value": "NaN", "order": "F",
      "filters": null, "dimension_separator": "/",
      "compressor": {"id": "blosc", "cname": "lz4", "clevel": 5, "shuffle": 1}})");
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->zarr_format, 2);
  EXPECT_EQ(m->shape, (std::vector<int64_t>{3, 150, 158, 96}));
  EXPECT_EQ(m->chunks, (std::vector<int64_t>{3, 128, 128, 96}));
  EXPECT_EQ(m->dtype, volume::DataType::kFloat64);
  EXPECT_TRUE(m->encoding.big_endian);
  ASSERT_TRUE(m->fill_value.has_value());
  EXPECT_TRUE(std::isnan(*m->fill_value));
  EXPECT_EQ(m->encoding.order, (std::vector<int>{3, 2, 1, 0}));
  EXPECT_EQ(m->separator, '/');
  EXPECT_EQ(m->key_prefix, "");
  EXPECT_EQ(m->encoding.codecs, (std::vector<ChunkCodec>{ChunkCodec::kBlosc}));
}

TEST(ZarrJson, V2DtypesCompressorsAndFillValues) {
  const std::pair<const char*, volume::DataType> types[] = {
      {"|u1", volume::DataType::kUint8},  {"|i1", volume::DataType::kInt8},
      {"<u2", volume::DataType::kUint16}, {">i2", volume::DataType::kInt16},
      {"<u4", volume::DataType::kUint32}, {"<i4", volume::DataType::kInt32},
      {"<f4", volume::DataType::kFloat32}};
  for (const auto& [code, type] : types) {
    auto m = ParseZarrArrayJson(std::string(R"({"zarr_format": 2, "shape": [1], "chunks": [1],
        "dtype": ")") + code + R"(", "compressor": null, "fill_value": null})");
    ASSERT_TRUE(m.ok()) << code << ": " << m.status().ToString();
    EXPECT_EQ(m->dtype, type) << code;
    EXPECT_FALSE(m->fill_value.has_value());
    EXPECT_TRUE(m->encoding.codecs.empty());
  }
  for (const char* id : {"zstd", "zlib", "gzip", "lz4"}) {
    auto m = ParseZarrArrayJson(std::string(R"({"zarr_format": 2, "shape": [1], "chunks": [1],
        "dtype": "<u2", "compressor": {"id": ")") +
                                id + R"("}, "fill_value": 3})");
    ASSERT_TRUE(m.ok()) << id;
    EXPECT_EQ(m->fill_value, 3.0);
    EXPECT_EQ(ChunkCodecName(m->encoding.codecs.at(0)), id);
  }
}

Status Array(const std::string& json) { return ParseZarrArrayJson(json).status(); }

TEST(ZarrJson, V2ErrorsNameTheKeyAndUnsupportedFeatures) {
  const std::string head = R"({"zarr_format": 2, "shape": [4, 4], "chunks": [2, 2], )";
  struct Case {
    std::string json;
    StatusCode code;
    const char* text;
  } cases[] = {
      {head + R"("dtype": "<u2", "filters": [{"id": "delta"}]})", StatusCode::kUnsupported,
       "delta"},
      {head + R"("dtype": "<u8"})", StatusCode::kUnsupported, "<u8"},
      {head + R"("dtype": "<f2"})", StatusCode::kUnsupported, "<f2"},
      {head + R"("dtype": "|u2"})", StatusCode::kCorrupt, "byte order"},
      {head + R"("dtype": [["a", "<u2"]]})", StatusCode::kUnsupported, "structured"},
      {head + R"("dtype": "<u2", "compressor": {"id": "bz2"}})", StatusCode::kUnsupported, "bz2"},
      {head + R"("dtype": "<u2", "order": "X"})", StatusCode::kCorrupt, "\"order\""},
      {head + R"("dtype": "<u2", "fill_value": 1.5})", StatusCode::kCorrupt, "fill_value"},
      {head + R"("dtype": "<u2", "dimension_separator": "-"})", StatusCode::kCorrupt,
       "dimension_separator"},
      {R"({"zarr_format": 2, "shape": [4, -1], "chunks": [2, 2], "dtype": "<u2"})",
       StatusCode::kCorrupt, "\"shape\"[1]"},
      {R"({"zarr_format": 2, "shape": [4, 4], "chunks": [2, 0], "dtype": "<u2"})",
       StatusCode::kCorrupt, "\"chunks\"[1]"},
      {R"({"zarr_format": 2, "shape": [4, 4], "dtype": "<u2"})", StatusCode::kCorrupt, "chunks"},
      {R"({"zarr_format": 4, "shape": [4], "chunks": [2], "dtype": "<u2"})",
       StatusCode::kUnsupported, "zarr_format"},
      {R"([1, 2])", StatusCode::kCorrupt, "object"},
      {R"({"zarr_format": 2, "shape": [4)", StatusCode::kCorrupt, "not valid JSON"},
      {R"({"zarr_format": 2, "shape": [99999999999999999999], "chunks": [1], "dtype": "<u2"})",
       StatusCode::kCorrupt, "shape"},
  };
  for (const Case& c : cases) {
    Status s = Array(c.json);
    EXPECT_EQ(s.code(), c.code) << c.json << " -> " << s.ToString();
    EXPECT_NE(s.message().find(c.text), std::string::npos) << s.message();
  }
}

TEST(ZarrJson, V3ArrayCodecsAndKeyEncodings) {
  auto m = ParseZarrArrayJson(R"({"zarr_format": 3, "node_type": "array", "shape": [10, 20],
      "data_type": "float32", "chunk_grid": {"name": "regular",
      "configuration": {"chunk_shape": [5, 5]}}, "chunk_key_encoding": {"name": "default",
      "configuration": {"separator": "."}}, "fill_value": "0x7fc00000",
      "codecs": [{"name": "transpose", "configuration": {"order": [1, 0]}},
                 {"name": "bytes", "configuration": {"endian": "big"}},
                 {"name": "zstd", "configuration": {"level": 1, "checksum": false}},
                 {"name": "crc32c"}],
      "dimension_names": ["y", "x"], "attributes": {"a": 1},
      "some_extension": {"must_understand": false}})");
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->zarr_format, 3);
  EXPECT_EQ(m->dtype, volume::DataType::kFloat32);
  EXPECT_TRUE(std::isnan(*m->fill_value));
  EXPECT_EQ(m->encoding.order, (std::vector<int>{1, 0}));
  EXPECT_TRUE(m->encoding.big_endian);
  EXPECT_EQ(m->encoding.codecs, (std::vector<ChunkCodec>{ChunkCodec::kZstd, ChunkCodec::kCrc32c}));
  EXPECT_EQ(m->key_prefix, "c");
  EXPECT_EQ(m->separator, '.');
  EXPECT_EQ(m->dimension_names, (std::vector<std::string>{"y", "x"}));

  auto v2keys = ParseZarrArrayJson(R"({"zarr_format": 3, "node_type": "array", "shape": [4],
      "data_type": "uint8", "chunk_grid": {"name": "regular", "configuration": {"chunk_shape":
      [2]}}, "chunk_key_encoding": {"name": "v2"}, "fill_value": 0,
      "codecs": [{"name": "bytes"}]})");
  ASSERT_TRUE(v2keys.ok()) << v2keys.status().ToString();
  EXPECT_EQ(v2keys->key_prefix, "");
  EXPECT_EQ(v2keys->separator, '.');
}

TEST(ZarrJson, V3Sharding) {
  auto m = ParseZarrArrayJson(R"({"zarr_format": 3, "node_type": "array", "shape": [64, 64],
      "data_type": "uint16", "chunk_grid": {"name": "regular", "configuration": {"chunk_shape":
      [32, 32]}}, "fill_value": 0, "codecs": [{"name": "sharding_indexed", "configuration": {
        "chunk_shape": [8, 8], "codecs": [{"name": "bytes", "configuration": {"endian":
        "little"}}, {"name": "blosc", "configuration": {"cname": "zstd", "clevel": 1, "shuffle":
        "bitshuffle", "typesize": 2, "blocksize": 0}}], "index_codecs": [{"name": "bytes",
        "configuration": {"endian": "little"}}, {"name": "crc32c"}], "index_location":
        "start"}}]})");
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  ASSERT_TRUE(m->sharding.has_value());
  EXPECT_EQ(m->sharding->inner_chunks, (std::vector<int64_t>{8, 8}));
  EXPECT_EQ(m->sharding->inner.codecs, (std::vector<ChunkCodec>{ChunkCodec::kBlosc}));
  EXPECT_FALSE(m->sharding->index_at_end);
  EXPECT_TRUE(m->sharding->index_crc32c);
}

TEST(ZarrJson, V3Unsupported) {
  const std::string head = R"({"zarr_format": 3, "node_type": "array", "shape": [4],
      "data_type": "uint8", "chunk_grid": {"name": "regular", "configuration": {"chunk_shape":
      [2]}}, "fill_value": 0, )";
  struct Case {
    std::string json;
    const char* text;
  } cases[] = {
      {head + R"("codecs": [{"name": "bytes"}, {"name": "bz2"}]})", "bz2"},
      {head + R"("codecs": [{"name": "bytes"}], "storage_transformers": [{"name": "x"}]})",
       "storage_transformers"},
      {head + R"("codecs": [{"name": "bytes"}], "my_ext": {"x": 1}})", "my_ext"},
      {head + R"("codecs": [{"name": "sharding_indexed", "configuration": {"chunk_shape": [1],
          "codecs": [{"name": "sharding_indexed", "configuration": {}}]}}]})",
       "nested sharding"},
      {R"({"zarr_format": 3, "node_type": "array", "shape": [4], "data_type": "complex64",
          "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": [2]}},
          "codecs": [{"name": "bytes"}]})",
       "complex64"},
      {R"({"zarr_format": 3, "node_type": "array", "shape": [4], "data_type": "uint8",
          "chunk_grid": {"name": "rectilinear"}, "codecs": [{"name": "bytes"}]})",
       "rectilinear"},
  };
  for (const Case& c : cases) {
    Status s = Array(c.json);
    EXPECT_EQ(s.code(), StatusCode::kUnsupported) << c.json << " -> " << s.ToString();
    EXPECT_NE(s.message().find(c.text), std::string::npos) << s.message();
  }
  EXPECT_EQ(Array(head + R"("codecs": [{"name": "zstd"}]})").code(), StatusCode::kCorrupt);
  EXPECT_EQ(Array(head + R"("codecs": []})").code(), StatusCode::kCorrupt);
}

TEST(ZarrJson, Ngff04Attributes) {
  auto a = ParseZarrAttributesJson(R"({"multiscales": [{"version": "0.4", "name": "img",
      "axes": [{"name": "c", "type": "channel"}, {"name": "z", "type": "space", "unit":
      "micrometer"}, {"name": "y", "type": "space", "unit": "micrometer"}, {"name": "x",
      "type": "space", "unit": "micrometer"}],
      "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale":
      [1, 2, 0.5, 0.5]}, {"type": "translation", "translation": [0, 1, 0, 0]}]},
      {"path": "1", "coordinateTransformations": [{"type": "scale", "scale": [1, 2, 1, 1]}]}],
      "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 2, 2]}]}],
      "omero": {"channels": [{"label": "DAPI", "color": "0000FF", "window": {"min": 0, "max":
      255, "start": 5, "end": 100}}, {"label": "bad colour", "color": "blue", "window": {"start":
      "x"}}]}})");
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  ASSERT_EQ(a->multiscales.size(), 1u);
  const io::NgffMultiscale& m = a->multiscales[0];
  EXPECT_EQ(m.version, "0.4");
  ASSERT_EQ(m.axes.size(), 4u);
  EXPECT_EQ(m.axes[1].unit, "micrometer");
  EXPECT_EQ(m.axes[0].type, "channel");
  ASSERT_EQ(m.datasets.size(), 2u);
  EXPECT_EQ(m.datasets[0].transform.scale, (std::vector<double>{1, 2, 0.5, 0.5}));
  EXPECT_EQ(m.datasets[0].transform.translation, (std::vector<double>{0, 1, 0, 0}));
  EXPECT_EQ(m.transform.scale, (std::vector<double>{1, 1, 2, 2}));
  ASSERT_EQ(a->omero_channels.size(), 2u);
  EXPECT_EQ(a->omero_channels[0].label, "DAPI");
  EXPECT_EQ(*a->omero_channels[0].color, (volume::Rgba{0, 0, 255, 255}));
  EXPECT_EQ(*a->omero_channels[0].window, (volume::DisplayWindow{5, 100, 0.0, 255.0}));
  // Malformed display hints are ignored, not fatal.
  EXPECT_FALSE(a->omero_channels[1].color.has_value());
  EXPECT_FALSE(a->omero_channels[1].window.has_value());
}

TEST(ZarrJson, Ngff03StringAxesAndV3GroupWithOme) {
  auto a = ParseZarrAttributesJson(R"({"multiscales": [{"version": "0.3", "axes": ["z", "y",
      "x"], "datasets": [{"path": "0"}]}]})");
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->multiscales[0].axes[2].name, "x");
  EXPECT_EQ(a->multiscales[0].axes[2].type, "");

  auto v3 = ParseZarrAttributesJson(R"({"zarr_format": 3, "node_type": "group", "attributes":
      {"ome": {"version": "0.5", "multiscales": [{"axes": [{"name": "y", "type": "space"},
      {"name": "x", "type": "space"}], "datasets": [{"path": "s0"}]}], "omero": {"channels":
      [{"label": "a", "color": "FF000080"}]}}}})");
  ASSERT_TRUE(v3.ok()) << v3.status().ToString();
  EXPECT_EQ(v3->node_type, "group");
  EXPECT_EQ(v3->multiscales[0].version, "0.5");
  EXPECT_EQ(v3->multiscales[0].datasets[0].path, "s0");
  EXPECT_EQ(*v3->omero_channels[0].color, (volume::Rgba{255, 0, 0, 128}));

  auto array = ParseZarrAttributesJson(R"({"zarr_format": 3, "node_type": "array"})");
  ASSERT_TRUE(array.ok());
  EXPECT_EQ(array->node_type, "array");
}

TEST(ZarrJson, SeriesAndPlateGroups) {
  auto b2r = ParseZarrAttributesJson(R"({"bioformats2raw.layout": 3})");
  ASSERT_TRUE(b2r.ok());
  EXPECT_EQ(b2r->bioformats2raw_layout, 3);
  auto plate = ParseZarrAttributesJson(R"({"plate": {"rows": []}})");
  ASSERT_TRUE(plate.ok());
  EXPECT_TRUE(plate->is_plate);
}

TEST(ZarrJson, AttributeErrorsNameTheKey) {
  Status s = ParseZarrAttributesJson(R"({"multiscales": [{"datasets": [{"pth": "0"}]}]})").status();
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_NE(s.message().find("\"multiscales\"[0].datasets[0]"), std::string::npos) << s.message();
  s = ParseZarrAttributesJson(R"({"multiscales": [{"datasets": [{"path": "0",
      "coordinateTransformations": [{"type": "scale", "scale": [1, "a"]}]}]}]})")
          .status();
  EXPECT_NE(s.message().find("scale[1]"), std::string::npos) << s.message();
  s = ParseZarrAttributesJson(R"({"multiscales": [{"datasets": [{"path": "0",
      "coordinateTransformations": [{"type": "affine"}]}]}]})")
          .status();
  EXPECT_EQ(s.code(), StatusCode::kUnsupported);
}

TEST(ZarrJson, HostileDocumentsNeverThrow) {
  std::string deep(100000, '[');
  EXPECT_EQ(ParseZarrArrayJson(deep).status().code(), StatusCode::kCorrupt);
  EXPECT_EQ(ParseZarrAttributesJson("{\"a\":" + deep).status().code(), StatusCode::kCorrupt);
  for (const char* text : {"", "null", "\"x\"", "{\"multiscales\": 5}", "{\"omero\": []}",
                           "{\"zarr_format\": 3}", "{\"zarr_format\": \"2\"}",
                           "{\"zarr_format\": 2, \"shape\": {}, \"chunks\": 1, \"dtype\": 2}"}) {
    EXPECT_FALSE(ParseZarrArrayJson(text).ok()) << text;
    (void)ParseZarrAttributesJson(text);
  }
}

}  // namespace
}  // namespace octoscope::protocol
