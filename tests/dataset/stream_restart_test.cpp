// Streams outlive the process (issue 28), in-process: a DatasetRegistry closed as the server's
// shutdown closes it and created again on the same cache root and state folder lists every stream
// as it was — id, name, shape, spacing, channel names, creator, state, planes received, histogram
// —; an unfinished one goes on (replacements exact) and finishes, a finished one opens from its
// complete cache. After an unclean stop (the process killed after a checkpoint, with the pool
// changed since) a stream resumes at exactly its checkpoint and says which planes to send again.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "dataset/dataset_registry.h"
#include "dataset/stream_test_volume.h"
#include "util/file_reading.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;
using testing::Bytes;
using testing::ExpectExactly;
using testing::kChannels;
using testing::kX;
using testing::kY;
using testing::kZ;
using testing::Planes;

class StreamRestartTest : public testing::StreamTestRoot {
 protected:
  RegistryOptions Options() const {
    RegistryOptions options;
    options.cache_root = root_ / "cache";
    options.state_dir = root_ / "state";
    options.ram_bytes = uint64_t{256} << 20;
    // No checkpoints but the ones a test asks for (a release, a close).
    options.stream_checkpoint_quiet = std::chrono::hours(1);
    options.stream_checkpoint_interval = std::chrono::hours(1);
    return options;
  }
  std::unique_ptr<DatasetRegistry> Start() const {
    auto registry = DatasetRegistry::Create(Options());
    EXPECT_TRUE(registry.ok()) << registry.status().ToString();
    return registry.ok() ? std::move(*registry) : nullptr;
  }
  static protocol::StreamRequest Request(const std::string& name) {
    protocol::StreamRequest r;
    r.name = name;
    r.size = {kX, kY, kZ};
    r.channels = kChannels;
    r.dtype = volume::DataType::kUint16;
    r.spacing_um = {0.5, 0.25, 3};
    r.channel_names = {"nuclei", ""};
    return r;
  }
  static void Add(Dataset& ds, int c, int64_t z0, int64_t nz) {
    const Status s = ds.AddSlab(c, z0, nz, Bytes(Planes(c, z0, nz)), true);
    ASSERT_TRUE(s.ok()) << s.ToString();
  }
  static void AddWrong(Dataset& ds, int c, int64_t z) {
    const std::vector<uint16_t> wrong(kX * kY, 64000);
    ASSERT_TRUE(ds.AddSlab(c, z, 1, Bytes(wrong), true).ok());
  }
  static mode_t Mode(const fs::path& path) {
    struct stat st;
    return ::stat(path.c_str(), &st) == 0 ? (st.st_mode & 0777) : 0;
  }
};

// What must be the same after a restart.
void ExpectSameStream(const Dataset& a, const Dataset& b) {
  EXPECT_EQ(a.id(), b.id());
  EXPECT_EQ(a.name(), b.name());
  EXPECT_EQ(a.creator(), b.creator());
  EXPECT_EQ(a.info().size, b.info().size);
  EXPECT_EQ(a.info().dtype, b.info().dtype);
  ASSERT_EQ(a.info().channel_count(), b.info().channel_count());
  for (int c = 0; c < a.info().channel_count(); ++c) {
    EXPECT_EQ(a.info().channels[c].name, b.info().channels[c].name);
  }
  EXPECT_EQ(a.spacing_um(), b.spacing_um());
  const DatasetStatus sa = a.status(), sb = b.status();
  EXPECT_EQ(sa.state, sb.state);
  EXPECT_EQ(sa.planes_received, sb.planes_received);
  EXPECT_EQ(sa.missing_planes, sb.missing_planes);
  const Histogram ha = a.histogram(), hb = b.histogram();
  ASSERT_EQ(ha.channels(), hb.channels());
  for (int c = 0; c < ha.channels(); ++c) {
    EXPECT_TRUE(std::equal(ha.counts(c).begin(), ha.counts(c).end(), hb.counts(c).begin()))
        << "channel " << c;
  }
}

TEST_F(StreamRestartTest, ARestartListsEveryStreamAsItWasAndTheyGoOn) {
  std::unique_ptr<DatasetRegistry> before = Start();
  ASSERT_NE(before, nullptr);
  auto a = before->CreateStream(Request("run a"), "alice");
  auto b = before->CreateStream(Request("run b"), "bob");
  ASSERT_TRUE(a.ok() && b.ok());
  std::shared_ptr<Dataset> unfinished = *a, finished = *b;
  ASSERT_NO_FATAL_FAILURE(Add(*unfinished, 0, 0, 10));
  ASSERT_NO_FATAL_FAILURE(Add(*unfinished, 1, 0, 5));
  ASSERT_NO_FATAL_FAILURE(AddWrong(*unfinished, 0, 3));
  ASSERT_NO_FATAL_FAILURE(Add(*unfinished, 0, 3, 1));
  for (int c = 0; c < kChannels; ++c) ASSERT_NO_FATAL_FAILURE(Add(*finished, c, 0, kZ));
  ASSERT_TRUE(finished->Finish().ok());
  before->Close();  // What SIGTERM does: unfinished streams checkpointed, never finished.
  EXPECT_EQ(unfinished->status().state, DatasetState::kStreaming);

  // The records: private, one per stream.
  const fs::path records = root_ / "state" / "streams";
  EXPECT_EQ(Mode(records), 0700u);
  EXPECT_EQ(Mode(records / (unfinished->id() + ".json")), 0600u);
  EXPECT_EQ(Mode(records / (finished->id() + ".json")), 0600u);

  std::unique_ptr<DatasetRegistry> after = Start();
  ASSERT_NE(after, nullptr);
  EXPECT_TRUE(after->restore_messages().empty());
  ASSERT_EQ(after->List().size(), 2u);
  EXPECT_EQ(after->List()[0]->id(), unfinished->id());  // Creation order.
  std::shared_ptr<Dataset> resumed = after->Find(unfinished->id());
  std::shared_ptr<Dataset> done = after->Find(finished->id());
  ASSERT_TRUE(resumed && done);
  ExpectSameStream(*resumed, *unfinished);
  ExpectSameStream(*done, *finished);
  EXPECT_EQ(resumed->creator(), "alice");
  EXPECT_EQ(resumed->status().state, DatasetState::kStreaming);
  EXPECT_FALSE(resumed->status().open);
  EXPECT_TRUE(resumed->status().warnings.empty());
  EXPECT_EQ(done->status().state, DatasetState::kReady);
  EXPECT_EQ(done->status().missing_planes, uint64_t{0});

  // The finished stream opens from its complete cache.
  ASSERT_TRUE(after->Open(done->id()).ok());
  ASSERT_TRUE(done->WaitFor([](const DatasetStatus& s) { return s.open && s.histogram_complete; },
                            std::chrono::seconds(10)));
  ExpectExactly(*done, {{0, 0, kZ}, {1, 0, kZ}});
  EXPECT_EQ(done->AddSlab(0, 0, 1, Bytes(Planes(0, 0, 1)), true).code(),
            StatusCode::kFailedPrecondition);

  // The unfinished one goes on: a plane sent before the restart is replaced, the rest arrives,
  // and it finishes.
  ASSERT_NO_FATAL_FAILURE(AddWrong(*resumed, 0, 5));
  EXPECT_EQ(resumed->histogram().counts(0)[64000], uint64_t{kX} * kY);
  ASSERT_NO_FATAL_FAILURE(Add(*resumed, 0, 5, 1));
  ExpectExactly(*resumed, {{0, 0, 10}, {1, 0, 5}});
  ASSERT_NO_FATAL_FAILURE(Add(*resumed, 0, 10, kZ - 10));
  ASSERT_TRUE(resumed->Finish().ok());
  EXPECT_EQ(resumed->status().missing_planes, uint64_t{kZ - 5});
  ExpectExactly(*resumed, {{0, 0, kZ}, {1, 0, 5}});
  after->Close();

  // Finished now, and listed so after the next start.
  std::unique_ptr<DatasetRegistry> third = Start();
  ASSERT_NE(third, nullptr);
  std::shared_ptr<Dataset> again = third->Find(unfinished->id());
  ASSERT_NE(again, nullptr);
  ExpectSameStream(*again, *resumed);
  // Records of another cache root are not this server's: left alone, not listed.
  RegistryOptions other = Options();
  other.cache_root = root_ / "other-cache";
  auto elsewhere = DatasetRegistry::Create(other);
  ASSERT_TRUE(elsewhere.ok());
  EXPECT_TRUE((*elsewhere)->List().empty());
  EXPECT_TRUE(fs::exists(records / (unfinished->id() + ".json")));
}

TEST_F(StreamRestartTest, AnUncleanStopResumesAtTheLastCheckpointAndSaysWhatToSendAgain) {
  std::unique_ptr<DatasetRegistry> registry = Start();
  ASSERT_NE(registry, nullptr);
  auto created = registry->CreateStream(Request("killed run"), "alice");
  ASSERT_TRUE(created.ok());
  std::shared_ptr<Dataset> ds = *created;
  ASSERT_NO_FATAL_FAILURE(Add(*ds, 0, 0, 10));
  ASSERT_TRUE(ds->Release(std::chrono::milliseconds(0)).ok());  // Checkpointed (and closed).
  // After the checkpoint: new planes, and planes of the checkpoint replaced in place, and the
  // pool written — then the process is killed (what is on disk is copied aside as it is).
  ASSERT_NO_FATAL_FAILURE(Add(*ds, 0, 10, 5));
  ASSERT_NO_FATAL_FAILURE(AddWrong(*ds, 0, 3));
  ASSERT_NO_FATAL_FAILURE(Add(*ds, 1, 0, kZ));
  ASSERT_TRUE(ds->octree()->Flush().ok());
  const fs::path cache = ds->cache_dir(), image = root_ / "image";
  fs::copy(cache, image, fs::copy_options::recursive);
  registry.reset();
  ds.reset();
  fs::remove_all(cache);
  fs::rename(image, cache);

  std::unique_ptr<DatasetRegistry> after = Start();
  ASSERT_NE(after, nullptr);
  std::shared_ptr<Dataset> resumed = after->Find(created.value()->id());
  ASSERT_NE(resumed, nullptr);
  DatasetStatus st = resumed->status();
  EXPECT_EQ(st.state, DatasetState::kStreaming);
  EXPECT_EQ(st.planes_received, 10u);
  ASSERT_EQ(st.warnings.size(), 1u);
  EXPECT_NE(st.warnings[0].find("send again every plane not stored: channel 0: z 10-22; "
                                "channel 1: z 0-22"),
            std::string::npos)
      << st.warnings[0];
  ASSERT_EQ(after->restore_messages().size(), 1u);  // For the log.
  // Exactly the checkpoint: the replaced plane is the original again, the rest is gone.
  ASSERT_NO_FATAL_FAILURE(Add(*resumed, 0, 10, 1));
  ExpectExactly(*resumed, {{0, 0, 11}});
  ASSERT_NO_FATAL_FAILURE(Add(*resumed, 0, 11, kZ - 11));
  ASSERT_NO_FATAL_FAILURE(Add(*resumed, 1, 0, kZ));
  ASSERT_TRUE(resumed->Finish().ok());
  EXPECT_EQ(resumed->status().missing_planes, uint64_t{0});
  ExpectExactly(*resumed, {{0, 0, kZ}, {1, 0, kZ}});
  // The warning stays with the stream (its record) until it is gone for good.
  after->Close();
  std::unique_ptr<DatasetRegistry> third = Start();
  ASSERT_NE(third, nullptr);
  EXPECT_EQ(third->Find(resumed->id())->status().warnings, st.warnings);
}

}  // namespace
}  // namespace octoscope::dataset
