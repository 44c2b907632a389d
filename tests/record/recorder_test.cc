// The Recorder alone, fed hand-made detection events: the disk cap, the
// bounded queue, write failures, and the cell's recording section.
#include <gtest/gtest.h>

#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <random>

#include "core/cell.h"
#include "grasp/bin_picking_planner.h"
#include "pipeline/recording.h"
#include "record/recorder.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

namespace fs = std::filesystem;

Frame MakeFrame(uint32_t seed, int w = 64, int h = 48) {
  std::mt19937 rng{seed};
  std::uniform_real_distribution<float> z(0.9f, 1.1f);
  Frame f;
  f.intrinsics.width = w;
  f.intrinsics.height = h;
  f.intrinsics.fx = f.intrinsics.fy = 60.0;
  f.intrinsics.cx = (w - 1) / 2.0;
  f.intrinsics.cy = (h - 1) / 2.0;
  f.depth = DepthImage(w, h);
  f.intensity = IntensityImage(w, h);
  for (size_t i = 0; i < f.depth.data.size(); ++i) {
    f.depth.data[i] = i % 17 == 0 ? std::numeric_limits<float>::quiet_NaN() : z(rng);
    f.intensity.data[i] = static_cast<uint8_t>(rng() & 0xFF);
  }
  f.source = "test frame " + std::to_string(seed);
  return f;
}

DetectionEvent Event(uint32_t seed) {
  DetectionEvent e;
  e.task_id = 0;
  e.request.task.id = 0;
  e.request.X_BF = MakePose(Mat3::Identity(), Vec3(0.5, 0.0, 0.6));
  e.scene = std::make_shared<CapturedFrame>(MakeFrame(seed));
  PlanResult r;
  r.outcome = PlanResult::Outcome::kGrasps;
  r.detections = 1;
  Grasp g;
  g.X_BT = MakePose(Mat3::Identity(), Vec3(0.7, 0.01 * seed, 0.1));
  r.grasps.push_back(g);
  e.plan = r;
  e.time = std::chrono::system_clock::now();
  return e;
}

int64_t DiskBytes(const fs::path& root) {
  int64_t total = 0;
  for (const auto& entry : fs::recursive_directory_iterator(root)) {
    if (entry.is_regular_file()) total += static_cast<int64_t>(entry.file_size());
  }
  return total;
}

Cell TestCell() {
  Result<Cell> cell = LoadDefaultCell();
  EXPECT_TRUE(cell.ok());
  return *cell;
}

TEST(Recorder, RotationKeepsTheDiskUnderTheCapOldestSessionsFirst) {
  const std::string root = testing::FreshDir("rot");
  // Two sessions of earlier runs, 300 kB each.
  for (const char* old : {"session_20000101T000000.000Z_1", "session_20010101T000000.000Z_1"}) {
    fs::create_directories(fs::path(root) / old);
    testing::WriteText((fs::path(root) / old / "blob").string(), std::string(300000, 'x'));
  }
  RecorderOptions o;
  o.directory = root;
  o.max_disk_bytes = 1000000;
  auto recorder = Recorder::Start(TestCell(), o);
  ASSERT_TRUE(recorder.ok()) << recorder.status().ToString();
  bool saw_only_newer_old_session = false;
  for (uint32_t i = 1; i <= 30; ++i) {
    (*recorder)->OnDetection(Event(i));
    (*recorder)->Flush();
    EXPECT_LE(DiskBytes(root), o.max_disk_bytes) << "after capture " << i;
    if (!fs::exists(fs::path(root) / "session_20000101T000000.000Z_1") &&
        fs::exists(fs::path(root) / "session_20010101T000000.000Z_1")) {
      saw_only_newer_old_session = true;
    }
  }
  (*recorder)->Stop();
  const RecorderStats s = (*recorder)->stats();
  EXPECT_TRUE(saw_only_newer_old_session) << "the oldest session goes first";
  EXPECT_EQ(s.sessions_rotated, 2u);
  EXPECT_GT(s.records_rotated, 0u);
  EXPECT_EQ(s.captures_recorded, 30u);
  EXPECT_EQ(s.disk_bytes, DiskBytes(root));  // the accounting matches the disk
  // The newest records survive, the oldest of this session went.
  const std::string session = (*recorder)->session_dir();
  EXPECT_TRUE(fs::exists(session + "/cap_000030/record.json"));
  EXPECT_FALSE(fs::exists(session + "/cap_000001"));
  EXPECT_TRUE(fs::exists(session + "/session.json"));
  Result<RecordListing> listing = ListRecords(session);
  ASSERT_TRUE(listing.ok());
  EXPECT_TRUE(listing->skipped.empty()) << ::testing::PrintToString(listing->skipped);
  EXPECT_EQ(listing->records.back(), session + "/cap_000030");
}

TEST(Recorder, AFullQueueDropsCapturesWithoutBlockingTheCaller) {
  const std::string root = testing::FreshDir("queue");
  std::mutex m;
  std::condition_variable cv;
  bool release = false;
  int writes_started = 0;
  RecorderOptions o;
  o.directory = root;
  o.queue_captures = 1;
  o.before_write = [&] {
    std::unique_lock lock(m);
    ++writes_started;
    cv.notify_all();
    cv.wait(lock, [&] { return release; });
  };
  auto recorder = Recorder::Start(TestCell(), o);
  ASSERT_TRUE(recorder.ok());
  (*recorder)->OnDetection(Event(1));  // taken by the writer, which blocks
  {
    std::unique_lock lock(m);
    cv.wait(lock, [&] { return writes_started == 1; });
  }
  (*recorder)->OnDetection(Event(2));  // queued
  for (uint32_t i = 3; i <= 5; ++i) (*recorder)->OnDetection(Event(i));  // dropped, returns at once
  EXPECT_EQ((*recorder)->stats().captures_dropped, 3u);
  {
    std::lock_guard lock(m);
    release = true;
  }
  cv.notify_all();
  (*recorder)->Stop();
  EXPECT_EQ((*recorder)->stats().captures_recorded, 2u);
  Result<RecordListing> listing = ListRecords((*recorder)->session_dir());
  ASSERT_TRUE(listing.ok());
  EXPECT_EQ(listing->records.size(), 2u);
}

TEST(Recorder, AWriteFailurePausesRecordingThenItResumes) {
  const std::string root = testing::FreshDir("fail");
  RecorderOptions o;
  o.directory = root;
  o.retry_after = std::chrono::milliseconds(200);
  auto recorder = Recorder::Start(TestCell(), o);
  ASSERT_TRUE(recorder.ok());
  Recorder& r = **recorder;
  r.OnDetection(Event(1));
  r.Flush();
  ASSERT_EQ(r.stats().captures_recorded, 1u);
  // The session directory turns into a file: every write fails (as on a full
  // or read-only disk; root ignores permissions, so this is how a test breaks it).
  const std::string session = r.session_dir();
  fs::rename(session, session + ".moved");
  testing::WriteText(session, "not a directory");
  r.OnDetection(Event(2));
  r.Flush();
  RecorderStats s = r.stats();
  EXPECT_TRUE(s.paused);
  EXPECT_EQ(s.captures_failed, 1u);
  EXPECT_NE(s.last_error.find(session), std::string::npos) << s.last_error;
  EXPECT_FALSE(fs::exists(session + ".moved/cap_000002.partial"));
  r.OnDetection(Event(3));  // paused: not even tried
  r.Flush();
  EXPECT_EQ(r.stats().captures_failed, 2u);
  // The disk comes back; after the pause recording resumes.
  fs::remove(session);
  fs::rename(session + ".moved", session);
  std::this_thread::sleep_for(std::chrono::milliseconds(250));
  r.OnDetection(Event(4));
  r.Flush();
  s = r.stats();
  EXPECT_FALSE(s.paused);
  EXPECT_EQ(s.captures_recorded, 2u);
  r.Stop();
  Result<RecordListing> listing = ListRecords(session);
  ASSERT_TRUE(listing.ok());
  EXPECT_EQ(listing->records, (std::vector<std::string>{session + "/cap_000001", session + "/cap_000002"}));
}

TEST(Recorder, AFlippedByteInARecordedFileFailsVerification) {
  const std::string root = testing::FreshDir("flip");
  RecorderOptions o;
  o.directory = root;
  auto recorder = Recorder::Start(TestCell(), o);
  ASSERT_TRUE(recorder.ok());
  (*recorder)->OnDetection(Event(1));
  (*recorder)->Stop();
  const std::string record = (*recorder)->session_dir() + "/cap_000001";
  ASSERT_TRUE(VerifyRecord(record).ok()) << VerifyRecord(record).ToString();
  const std::string pcd = record + "/cloud.pcd";
  std::string bytes = testing::ReadBytes(pcd);
  bytes[bytes.size() - 5] ^= 0x01;  // same size, one bit off
  testing::WriteText(pcd, bytes);
  const Status s = VerifyRecord(record);
  EXPECT_EQ(s.code(), Status::Code::kCorruption);
  EXPECT_NE(s.message().find("cloud.pcd': checksum does not match"), std::string::npos) << s.ToString();
}

TEST(Recorder, StartFailsWithThePathWhenTheDirectoryCannotBeCreated) {
  const std::string root = testing::FreshDir("nodir");
  testing::WriteText(root + "/file", "x");
  RecorderOptions o;
  o.directory = root + "/file/recordings";
  auto recorder = Recorder::Start(TestCell(), o);
  ASSERT_FALSE(recorder.ok());
  EXPECT_NE(recorder.status().message().find(o.directory), std::string::npos) << recorder.status().ToString();
}

TEST(CellRecording, DefaultsOnAndStrictKeys) {
  const Cell def = TestCell();
  EXPECT_TRUE(def.recording.enabled);
  EXPECT_EQ(def.recording.max_disk_mb, 1024);
  const std::string text = def.yaml_text;
  ASSERT_FALSE(text.empty());
  const std::string dir = testing::FreshDir("cell");
  const std::string cell_path = AssetsDir() + "/cells/recording_test.yaml";  // meshes resolve
  Result<Cell> c = ParseCell(text + "\nrecording: {enabled: false, directory: " + dir +
                                 "/rec, max_disk_mb: 5, queue_captures: 3}\n",
                             cell_path);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_FALSE(c->recording.enabled);
  EXPECT_EQ(c->recording.directory, dir + "/rec");
  EXPECT_EQ(c->recording.max_disk_mb, 5);
  EXPECT_EQ(c->recording.queue_captures, 3);
  EXPECT_EQ(RecorderOptionsFromCell(*c).max_disk_bytes, 5 << 20);
  Result<Cell> bad = ParseCell(text + "\nrecording: {max_disk_mb: 0}\n", cell_path);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("recording.max_disk_mb: must be >= 1"), std::string::npos)
      << bad.status().ToString();
  Result<Cell> unknown = ParseCell(text + "\nrecording: {enable: true}\n", cell_path);
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.status().message().find("enable"), std::string::npos) << unknown.status().ToString();
}

TEST(ConfigHash, ChangesWithTheCellAndTheTask) {
  Cell a = TestCell();
  Cell b = a;
  b.yaml_text += "\n# edited\n";
  EXPECT_EQ(ConfigHash(a, 0), ConfigHash(a, 0));
  EXPECT_NE(ConfigHash(a, 0), ConfigHash(a, 1));
  EXPECT_NE(ConfigHash(a, 0), ConfigHash(b, 0));
  EXPECT_EQ(ConfigHash(a, 0).size(), 16u);
  EXPECT_EQ(Hex64(Fnv1a64("a")), "af63dc4c8601ec8c");  // FNV-1a 64 reference value
}

}  // namespace
}  // namespace bp
