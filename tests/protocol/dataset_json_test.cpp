// Dataset JSON: the documents of docs/api.md as a client parses them (with an independent JSON
// parser), and strict parsing of stream requests and watch sidecars: every bad field is an error
// naming the document and the key; hostile documents are errors, never crashes.
#include "protocol/dataset_json.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

namespace octoscope::protocol {
namespace {

using nlohmann::json;

TEST(DatasetJsonTest, DescribesADatasetAsTheApiSays) {
  DatasetDescription d;
  d.id = "a3f09c21d4e1";
  d.name = "embryo.ome.tif";
  d.info.format = "ome-tiff";
  d.info.size = {1024, 512, 64};
  d.info.channels = {{"nuclei", volume::Rgba{0, 128, 255, 255}}, {"membranes", std::nullopt}};
  d.info.dtype = volume::DataType::kUint16;
  d.info.warnings = {"a warning"};
  d.spacing_um = {0.4, 0.4, 2.0};
  d.state = "building";
  d.planes_total = 128;
  d.planes_received = 40;
  d.planes_inserted = 32;
  d.cache = "/cache/a3f09c21d4e1";
  const json j = json::parse(DatasetJson(d));
  EXPECT_EQ(j["id"], "a3f09c21d4e1");
  EXPECT_EQ(j["name"], "embryo.ome.tif");
  EXPECT_EQ(j["format"], "ome-tiff");
  EXPECT_EQ(j["size"], json::array({1024, 512, 64}));
  EXPECT_EQ(j["channels"], 2);
  EXPECT_EQ(j["channel_names"], json::array({"nuclei", "membranes"}));
  EXPECT_DOUBLE_EQ(j["channel_colors"][0][1].get<double>(), 128 / 255.0);
  EXPECT_TRUE(j["channel_colors"][1].is_null());
  EXPECT_EQ(j["dtype"], "uint16");
  EXPECT_EQ(j["spacing"], json::array({0.4, 0.4, 2.0}));
  EXPECT_EQ(j["state"], "building");
  EXPECT_DOUBLE_EQ(j["progress"].get<double>(), 0.25);
  EXPECT_EQ(j["planes_total"], 128);
  EXPECT_EQ(j["planes_received"], 40);
  EXPECT_EQ(j["planes_inserted"], 32);
  EXPECT_TRUE(j["missing_planes"].is_null());
  EXPECT_EQ(j["cache"], "/cache/a3f09c21d4e1");
  EXPECT_TRUE(j["error"].is_null());
  EXPECT_EQ(j["warnings"], json::array({"a warning"}));
  EXPECT_TRUE(j["value_maps"].is_null());  // Not known before the octree is opened.
  volume::ValueMap floats;
  floats.file_type = volume::DataType::kFloat32;
  floats.offset = -1.5;
  floats.scale = 0.25;
  d.value_maps = {volume::ValueMap{}, floats};
  const json mapped = json::parse(DatasetJson(d));
  ASSERT_EQ(mapped["value_maps"].size(), 2u);
  EXPECT_EQ(mapped["value_maps"][0]["offset"], 0);
  EXPECT_EQ(mapped["value_maps"][0]["scale"], 1);
  EXPECT_EQ(mapped["value_maps"][1]["offset"], -1.5);
  EXPECT_EQ(mapped["value_maps"][1]["scale"], 0.25);
  EXPECT_EQ(mapped["value_maps"][1]["stored_max"], 65535);

  d.state = "error";
  d.error = "bad \xff bytes";  // Invalid UTF-8 from a file name must not break the document.
  d.missing_planes = 3;
  d.planes_total = 0;
  const json list = json::parse(DatasetListJson(std::vector<DatasetDescription>{d, d}));
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[1]["missing_planes"], 3);
  EXPECT_TRUE(list[1]["error"].is_string());
  EXPECT_EQ(list[1]["progress"], 0.0);
}

TEST(DatasetJsonTest, Histogram) {
  HistogramChannelDescription c;
  c.count = 10;
  c.min = 3;
  c.max = 4000;
  c.lo = 0;
  c.hi = 4096;
  c.bins.assign(256, 1);
  c.p001 = 3;
  c.p999 = 3999;
  const json j = json::parse(HistogramJson(std::vector<HistogramChannelDescription>{c}));
  ASSERT_EQ(j["channels"].size(), 1u);
  EXPECT_EQ(j["channels"][0]["bins"].size(), 256u);
  EXPECT_EQ(j["channels"][0]["hi"], 4096.0);
  EXPECT_EQ(j["channels"][0]["p999"], 3999.0);
  EXPECT_EQ(j["channels"][0]["count"], 10);
  EXPECT_EQ(json::parse(CreatedJson("abc"))["id"], "abc");
}

TEST(DatasetJsonTest, ParsesStreamRequests) {
  auto r = ParseStreamRequest(
      R"({"name": "run 42", "size": [512, 256, 100], "channels": 2, "dtype": "int16",
          "spacing": [0.5, 0.5, 2], "channel_names": ["a", "b"]})",
      StreamRequestKind::kApi, "request body");
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->name, "run 42");
  EXPECT_EQ(r->size, (std::array<int64_t, 3>{512, 256, 100}));
  EXPECT_EQ(r->channels, 2);
  EXPECT_EQ(r->dtype, volume::DataType::kInt16);
  EXPECT_EQ(r->spacing_um, (std::array<double, 3>{0.5, 0.5, 2}));
  EXPECT_EQ(r->channel_names, (std::vector<std::string>{"a", "b"}));
  EXPECT_EQ(r->index_base, 0);

  auto minimal = ParseStreamRequest(R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8"})",
                                    StreamRequestKind::kApi, "body");
  ASSERT_TRUE(minimal.ok()) << minimal.status().ToString();
  EXPECT_EQ(minimal->name, "");
  EXPECT_EQ(minimal->spacing_um, (std::array<double, 3>{1, 1, 1}));

  auto sidecar = ParseStreamRequest(
      R"({"size": [8, 8, 4], "channels": 1, "dtype": "uint16", "index_base": 1})",
      StreamRequestKind::kSidecar, "stream.json");
  ASSERT_TRUE(sidecar.ok()) << sidecar.status().ToString();
  EXPECT_EQ(sidecar->index_base, 1);
}

TEST(DatasetJsonTest, RefusesBadStreamRequests) {
  struct Bad {
    const char* json;
    const char* names;  // Text the message must contain.
  };
  const Bad bad[] = {
      {R"({"size": [1, 1], "channels": 1, "dtype": "uint8"})", "size"},
      {R"({"size": [0, 1, 1], "channels": 1, "dtype": "uint8"})", "size[0]"},
      {R"({"size": [65537, 1, 1], "channels": 1, "dtype": "uint8"})", "size[0]"},
      {R"({"size": [1, 1, 1.5], "channels": 1, "dtype": "uint8"})", "size[2]"},
      {R"({"size": [1, 1, 18446744073709551615], "channels": 1, "dtype": "uint8"})", "size[2]"},
      {R"({"size": [1, 1, 1], "channels": 65, "dtype": "uint8"})", "channels"},
      {R"({"size": [1, 1, 1], "channels": 0, "dtype": "uint8"})", "channels"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "float32"})", "dtype"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint32"})", "dtype"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": 16})", "dtype"},
      {R"({"size": [1, 1, 1], "channels": 1})", "dtype"},
      {R"({"channels": 1, "dtype": "uint8"})", "size"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8", "spacing": [1, 0, 1]})",
       "spacing[1]"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8", "spacing": [1, -1, 1]})",
       "spacing[1]"},
      {R"({"size": [1, 1, 1], "channels": 2, "dtype": "uint8", "channel_names": ["a"]})",
       "channel_names"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8", "channel_names": [3]})",
       "channel_names[0]"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8", "colour": 1})", "colour"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8", "index_base": 1})", "index_base"},
      {R"([1, 2, 3])", "object"},
      {R"({"size": [1, 1, 1], "channels": 1, "dtype": "uint8")", "JSON"},
      {R"({"size": [[[[[[1]]]]]], "channels": 1, "dtype": "uint8"})", "nested"},
  };
  for (const Bad& b : bad) {
    auto r = ParseStreamRequest(b.json, StreamRequestKind::kApi, "body");
    ASSERT_FALSE(r.ok()) << b.json;
    EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << b.json;
    EXPECT_NE(r.status().message().find(b.names), std::string::npos)
        << b.json << ": " << r.status().ToString();
    EXPECT_EQ(r.status().message().rfind("body", 0), 0u) << r.status().ToString();
  }
  const std::string long_name = std::string(R"({"name": ")") + std::string(300, 'x') +
                                R"(", "size": [1, 1, 1], "channels": 1, "dtype": "uint8"})";
  EXPECT_FALSE(ParseStreamRequest(long_name, StreamRequestKind::kApi, "body").ok());
  const std::string huge(kMaxStreamRequestBytes + 1, ' ');
  EXPECT_FALSE(ParseStreamRequest(huge, StreamRequestKind::kApi, "body").ok());
  const std::string deep = std::string(100000, '[') + std::string(100000, ']');
  EXPECT_FALSE(ParseStreamRequest(deep, StreamRequestKind::kApi, "body").ok());
}

// The fuzzer's seeds (and any regression it finds, kept beside them) parse or fail cleanly.
TEST(DatasetJsonTest, FuzzSeedsAreSafe) {
  const std::filesystem::path dir = std::filesystem::path(OCTOSCOPE_SOURCE_DIR) / "fuzz/seeds-json";
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    std::ifstream in(entry.path(), std::ios::binary);
    const std::string text((std::istreambuf_iterator<char>(in)), {});
    ++files;
    for (StreamRequestKind kind : {StreamRequestKind::kApi, StreamRequestKind::kSidecar}) {
      (void)ParseStreamRequest(text, kind, entry.path().filename().string());
    }
    auto record = ParseStreamRecord(text, entry.path().filename().string());
    if (entry.path().filename() == "stream-record.json") {
      EXPECT_TRUE(record.ok()) << record.status().ToString();  // A valid start for the fuzzer.
    }
  }
  EXPECT_GE(files, 3);
}

}  // namespace
}  // namespace octoscope::protocol

namespace octoscope::protocol {
namespace {

StreamRecord SampleRecord() {
  StreamRecord r;
  r.id = "k3j4h5g6f7d8";
  r.shape.name = "run 42 «ü»";
  r.shape.size = {1024, 512, 77};
  r.shape.channels = 2;
  r.shape.dtype = volume::DataType::kInt16;
  r.shape.spacing_um = {0.1, 0.30000000000000004, 2.5};
  r.shape.channel_names = {"nuclei", ""};
  r.creator = "alice";
  r.watch = "/srv/acq/run42";
  r.cache = "/var/cache/octoscope/k3j4h5g6f7d8";
  r.finished = true;
  r.missing_planes = 12;
  r.created_unix_ms = 1767225600123;
  r.warnings = {"the server stopped without checkpointing this stream"};
  return r;
}

void ExpectSameRecord(const StreamRecord& a, const StreamRecord& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.shape.name, b.shape.name);
  EXPECT_EQ(a.shape.size, b.shape.size);
  EXPECT_EQ(a.shape.channels, b.shape.channels);
  EXPECT_EQ(a.shape.dtype, b.shape.dtype);
  EXPECT_EQ(a.shape.spacing_um, b.shape.spacing_um);  // Exactly: the JSON round-trips doubles.
  EXPECT_EQ(a.shape.channel_names, b.shape.channel_names);
  EXPECT_EQ(a.creator, b.creator);
  EXPECT_EQ(a.watch, b.watch);
  EXPECT_EQ(a.cache, b.cache);
  EXPECT_EQ(a.finished, b.finished);
  EXPECT_EQ(a.missing_planes, b.missing_planes);
  EXPECT_EQ(a.created_unix_ms, b.created_unix_ms);
  EXPECT_EQ(a.warnings, b.warnings);
}

TEST(StreamRecordJsonTest, RoundTripsExactly) {
  const StreamRecord record = SampleRecord();
  auto parsed = ParseStreamRecord(StreamRecordJson(record), "record");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  ExpectSameRecord(*parsed, record);
  StreamRecord streaming = SampleRecord();
  streaming.finished = false;
  streaming.missing_planes.reset();
  streaming.watch.clear();
  streaming.shape.channel_names.clear();
  streaming.creator.clear();
  const std::string text = StreamRecordJson(streaming);
  EXPECT_NE(text.find(R"("watch":null)"), std::string::npos) << text;
  EXPECT_NE(text.find(R"("state":"streaming")"), std::string::npos) << text;
  parsed = ParseStreamRecord(text, "record");
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  ExpectSameRecord(*parsed, streaming);
}

TEST(StreamRecordJsonTest, IsReadStrictly) {
  const nlohmann::json good = nlohmann::json::parse(StreamRecordJson(SampleRecord()));
  struct Bad {
    const char* key;
    nlohmann::json value;  // null: the key is removed.
    const char* names;     // Text the message must contain.
  };
  const Bad bad[] = {
      {"version", 2, "version"},
      {"id", "DEMO", "id"},
      {"id", "abc", "id"},
      {"creator", nullptr, "creator"},
      {"creator", 7, "creator"},
      {"cache", "", "cache"},
      {"state", "finished", "state"},
      {"missing_planes", -1, "missing_planes"},
      {"watch", "", "watch"},
      {"warnings", "x", "warnings"},
      {"size", {1, 1}, "size"},
      {"channel_names", {"only one"}, "channel_names"},
      {"extra", 1, "extra"},
  };
  for (const Bad& b : bad) {
    nlohmann::json doc = good;
    if (b.value.is_null()) {
      doc.erase(b.key);
    } else {
      doc[b.key] = b.value;
    }
    auto r = ParseStreamRecord(doc.dump(), "streams/x.json");
    ASSERT_FALSE(r.ok()) << doc.dump();
    EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << doc.dump();
    EXPECT_NE(r.status().message().find(b.names), std::string::npos) << r.status().ToString();
    EXPECT_EQ(r.status().message().rfind("streams/x.json", 0), 0u) << r.status().ToString();
  }
  nlohmann::json streaming = good;
  streaming["state"] = "streaming";  // Missing planes belong to finished streams only.
  EXPECT_FALSE(ParseStreamRecord(streaming.dump(), "record").ok());
}

}  // namespace
}  // namespace octoscope::protocol
