// Hostile inputs to the `clothdb` command (docs/GUIDE.md#limits): every case exits non-zero with a
// message naming the argument, field or file and what is allowed, and creates or changes no file.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "runtime/tools/synthetic_db.hpp"
#include "support/cli.hpp"

namespace {

namespace fs = std::filesystem;
using Result = clothdb::test::CliResult;
const std::string kSource = CLOTHDB_SOURCE_DIR;

fs::path work_dir() {
  const fs::path dir =
      fs::path(testing::TempDir()) / ("clothdb_hostile_" + std::to_string(getpid()));
  fs::create_directories(dir);
  return dir;
}

std::string read_file(const std::string& path) {
  return clothdb::test::read_text(path);
}

Result clothdb(const std::vector<std::string>& args) {
  return clothdb::test::run_clothdb(args, (work_dir() / "log.txt").string());
}

// Every file under `dir` with its bytes: what a refused command must leave as it was.
std::vector<std::pair<std::string, std::string>> snapshot(const fs::path& dir) {
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    // SQLite's WAL index and log next to a database a reader opened (a read-only connection
    // cannot remove them on close); the database file itself is compared.
    const std::string name = e.path().string();
    if (name.size() > 4 && (name.ends_with("-shm") || name.ends_with("-wal"))) continue;
    if (e.path().filename() == "log.txt") continue;  // the commands' output, below
    out.push_back({e.path().string(), e.is_regular_file() ? read_file(e.path().string()) : "dir"});
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Runs `args`, expects a non-zero exit with every one of `words` in the output, and no change
// under the work directory.
void expect_refused(const std::vector<std::string>& args, const std::vector<std::string>& words) {
  const auto before = snapshot(work_dir());
  const Result r = clothdb(args);
  std::string cmd;
  for (const auto& a : args) cmd += a + " ";
  EXPECT_GT(r.code, 0) << cmd << "\n" << r.output;
  for (const std::string& w : words)
    EXPECT_NE(r.output.find(w), std::string::npos) << cmd << ": no '" << w << "' in\n" << r.output;
  EXPECT_EQ(r.output.find("179769313486231570"), std::string::npos) << "DBL_MAX in full";
  fs::remove(work_dir() / "log.txt");
  const auto after = snapshot(work_dir());
  std::string changed;
  for (const auto& f : after)
    if (std::find(before.begin(), before.end(), f) == before.end()) changed += f.first + " ";
  for (const auto& f : before)
    if (std::find(after.begin(), after.end(), f) == after.end()) changed += f.first + " ";
  EXPECT_TRUE(changed.empty()) << cmd << ": files were created or changed: " << changed;
}

std::string demo_db() {
  const std::string path = (work_dir() / "demo.clothdb").string();
  if (!fs::exists(path)) clothdb::synthetic::build(path, clothdb::synthetic::demo_spec(40));
  return path;
}

std::string scene_with(const std::string& name, const std::string& extra) {
  const std::string path = (work_dir() / (name + ".json")).string();
  std::ofstream(path) << R"({"manifest": ")" << kSource << R"(/motions/cmu_walk.json",
    "clips": ["01_03_level_walk"],
    "garment": {"type": "skirt", "bone": "Hips", "vertices": 200})"
                      << extra << "}";
  return path;
}

TEST(HostileInputs, PlayRefusesNumbersOutsideItsLimits) {
  const std::string db = demo_db();
  const std::string out = (work_dir() / "play_out").string();
  expect_refused({"play", db, "--out", out, "--seconds", "inf"}, {"--seconds inf", "[0, 3600]"});
  expect_refused({"play", db, "--out", out, "--view", "top"},
                 {"--view", "unknown view 'top'", "front, back or side"});
  expect_refused({"play", db, "--out", out, "--seconds", "nan"}, {"--seconds nan"});
  expect_refused({"play", db, "--out", out, "--seconds", "1e7"}, {"--seconds 1e+07", "[0, 3600]"});
  expect_refused({"play", db, "--out", out, "--seconds", "-1"}, {"--seconds -1"});
  expect_refused({"play", db, "--out", out, "--fps", "1e6"}, {"--fps 1e+06", "(0, 1000]"});
  expect_refused({"play", db, "--out", out, "--width", "0"}, {"--width 0", "[16, 8192]"});
  expect_refused({"play", db, "--out", out, "--height", "100000"}, {"[16, 8192]"});
  expect_refused({"play", db, "--out", out, "--blend-frames", "nan"}, {"--blend-frames"});
  expect_refused({"play", db, "--out", out, "--path", "random", "--seconds", "0"},
                 {"--path random needs --seconds > 0"});
  // The frame cap follows the garment size: a long clip at a high rate is refused before any
  // frame is played.
  expect_refused({"play", db, "--out", out, "--seconds", "3600", "--fps", "1000"},
                 {"frames of 1600 vertices; at most 111848 frames", "lower --seconds or --fps"});
  EXPECT_FALSE(fs::exists(out));
}

TEST(HostileInputs, PlayWritesEverythingOrNothing) {
  const std::string db = demo_db();
  const fs::path out = work_dir() / "play_ok";
  const Result r =
      clothdb({"play", db, "--out", out.string(), "--seconds", "2", "--preview-every", "0"});
  ASSERT_EQ(r.code, 0) << r.output;
  for (const char* f : {"garment.obj", "cloth.pc2", "path.csv"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  for (const auto& e : fs::directory_iterator(out))
    EXPECT_EQ(e.path().filename().string().find(".play-partial"), std::string::npos)
        << "staging directory left behind";
  // A rerun into the same directory that fails (a clip that is not there) changes nothing.
  expect_refused({"play", db, "--out", out.string(), "--path", "no_such_clip"},
                 {"no primary clip named or numbered 'no_such_clip'"});
  fs::remove_all(out);
}

// `simulate` writes into a hidden directory inside --out made before it simulates, and moves the
// files into place at the end: a bad --out is refused before any frame is simulated (it was found
// only after the whole clip), and no staging directory is left behind.
TEST(HostileInputs, SimulateChecksItsOutputFirstAndWritesEverythingOrNothing) {
  const std::string scene = scene_with("sim_stage", "");
  const fs::path file = work_dir() / "not_a_directory";
  std::ofstream(file) << "a file\n";
  expect_refused({"simulate", scene, "--frames", "3", "--out", file.string()},
                 {file.string() + ": exists and is not a directory"});
  const Result refused = clothdb({"simulate", scene, "--frames", "3", "--out", file.string()});
  EXPECT_EQ(refused.output.find("ms/frame"), std::string::npos)
      << "simulated before the output was checked:\n"
      << refused.output;
  const fs::path out = work_dir() / "sim_stage_out";
  const Result r =
      clothdb({"simulate", scene, "--frames", "3", "--preview-every", "2", "--out", out.string()});
  ASSERT_EQ(r.code, 0) << r.output;
  for (const char* f : {"garment.obj", "cloth.pc2", "body.obj", "body.pc2", "metrics.csv",
                        "summary.json", "previews/frame_0002.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  for (const auto& e : fs::directory_iterator(out))
    EXPECT_EQ(e.path().filename().string().find("-partial"), std::string::npos)
        << "staging directory left behind";
  fs::remove_all(out);
  fs::remove(file);
  fs::remove(scene);
}

TEST(HostileInputs, ThreadCountsAreCapped) {
  const std::string scene = scene_with("threads_ok", "");
  const std::string out = (work_dir() / "sim_out").string();
  expect_refused({"simulate", scene, "--out", out, "--threads", "100000"}, {"--threads", "100000"});
  expect_refused(
      {"simulate", scene_with("threads_scene", R"(, "solver": {"threads": 100000})"), "--out", out},
      {"threads_scene.json: solver.threads: must be an integer in [1, ", "(got 100000)"});
  fs::remove(work_dir() / "threads_ok.json");
  fs::remove(work_dir() / "threads_scene.json");
}

TEST(HostileInputs, SceneIntegersDoNotWrap) {
  const std::string out = (work_dir() / "sim_out").string();
  expect_refused({"simulate", scene_with("substeps", R"(, "solver": {"substeps": 1099511627776})"),
                  "--out", out},
                 {"substeps.json: solver.substeps: must be an integer in [1, 1000000] (got "
                  "1099511627776)"});
  expect_refused(
      {"simulate", scene_with("settle", R"(, "settle_frames": 10000000000)"), "--out", out},
      {"settle_frames: expected an integer in [0, 100000], got 10000000000"});
  expect_refused(
      {"simulate", scene_with("settle_float", R"(, "settle_frames": 1e10)"), "--out", out},
      {"settle_frames: expected an integer in [0, 100000]"});
  expect_refused({"simulate", scene_with("negative", R"(, "solver": {"iterations": -4294967295})"),
                  "--out", out},
                 {"solver.iterations: must be an integer in [1, 10000]"});
  for (const char* f : {"substeps", "settle", "settle_float", "negative"})
    fs::remove(work_dir() / (std::string(f) + ".json"));
}

TEST(HostileInputs, RangeErrorsAreShortAndRefuseNan) {
  const std::string out = (work_dir() / "graph.json").string();
  expect_refused(
      {"graph", "build", kSource + "/motions/cmu_walk.json", "--out", out, "--window", "-1"},
      {"--window", "-1 is not a number in (0, 1e+12]"});
  expect_refused(
      {"graph", "build", kSource + "/motions/cmu_walk.json", "--out", out, "--max-distance", "nan"},
      {"nan is not a number in [0, 1e+12]"});
}

// NaN passes CLI11's Range and PositiveNumber (every comparison with it is false), and a negative
// count wraps in an unsigned option: each of these ran before (some with NaN as a setting, `bench
// nearest --synthetic -5` for ever); now each is refused at parsing, naming the option and its
// range.
TEST(HostileInputs, NonsenseNumbersAreRefusedBeforeAnyWork) {
  const std::string db = demo_db();
  const std::string scene = scene_with("nonsense", "");
  const std::string out = (work_dir() / "nonsense_out").string();
  const std::string new_db = (work_dir() / "nonsense.clothdb").string();
  const std::string curve = (work_dir() / "curve.csv").string();
  std::ofstream(curve) << "cpu_seconds,frames,states,dead_ends,unexplored\n0,0,1,1,1\n1,10,2,1,1\n";
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"precompute", scene, "--db", new_db, "--epsilon", "nan"},
       "--epsilon: nan is not a number in (0, 1000]"},
      {{"precompute", scene, "--db", new_db, "--epsilon", "inf"}, "--epsilon: inf is not a number"},
      {{"precompute", scene, "--db", new_db, "--percentile", "-3"},
       "--percentile: -3 is not a number in (0, 100]"},
      {{"precompute", scene, "--db", new_db, "--state-cache-mb", "nan"}, "--state-cache-mb: nan"},
      {{"precompute", scene, "--db", new_db, "--floor-seconds", "nan"}, "--floor-seconds: nan"},
      {{"precompute", scene, "--db", new_db, "--auto-fraction", "nan"}, "--auto-fraction: nan"},
      {{"floor", scene, "--seconds", "nan"}, "--seconds: nan is not a number in [0, 600]"},
      {{"floor", scene, "--percentile", "nan"}, "--percentile: nan"},
      {{"db", "recode", db, "--bound-mm", "nan"},
       "--bound-mm: nan is not a number in [1e-06, 1000]"},
      {{"db", "recode", db, "--bound-mm", "-1"}, "--bound-mm: -1 is not a number"},
      {{"db", "recode", db, "--coefficient-step", "nan"}, "--coefficient-step: nan"},
      {{"forecast", curve, "--at", "0.5,nan"}, "--at: nan is not a number in [0, 1]"},
      {{"bench", "nearest", "--synthetic", "-5"}, "--synthetic: -5 is not a number"},
      {{"bench", "runtime", db, "--players", "-1"}, "--players: -1 is not a number"},
      {{"bench", "codec", "--db", db, "--rms-mm", "nan"}, "--rms-mm: nan"},
      {{"bench", "codec", "--db", db, "--codecs", "v1,v9"}, "--codecs: unknown codec 'v9'"},
      {{"bench", "character", scene, "--chebyshev-rho", "nan"}, "--chebyshev-rho: nan"},
      {{"simulate", scene, "--out", out, "--frames", "-1"}, "--frames: -1 is not a number"},
      {{"simulate", scene, "--out", out, "--preview-every", "-1"}, "--preview-every: -1"},
      {{"clip", "resim", db, "1", "--max-frames", "-1"}, "--max-frames: -1 is not a number"},
  };
  for (const auto& [args, words] : cases) expect_refused(args, {words});
  EXPECT_FALSE(fs::exists(new_db));
  EXPECT_FALSE(fs::exists(out));
  fs::remove(curve);
  fs::remove(work_dir() / "nonsense.json");
}

// `graph show` reads a graph JSON or a database: a file that is neither is named as such (it was
// reported as bad JSON at its first byte), and a database's own error is not prefixed twice.
TEST(HostileInputs, GraphShowNamesAFileThatIsNeitherKind) {
  const fs::path text = work_dir() / "notes.db";
  std::ofstream(text) << "hello, not a database\n";
  expect_refused({"graph", "show", text.string()},
                 {text.string() + ": neither a clothdb database nor a motion graph"});
  const fs::path empty = work_dir() / "empty.db";
  std::ofstream{empty};
  expect_refused({"graph", "show", empty.string()},
                 {empty.string() + ": neither a clothdb database nor a motion graph"});
  const fs::path cut = work_dir() / "cut.db";
  {
    const std::string whole = read_file(demo_db());
    std::ofstream(cut, std::ios::binary) << whole.substr(0, whole.size() / 3);
  }
  const Result r = clothdb({"graph", "show", cut.string()});
  EXPECT_GT(r.code, 0) << r.output;
  EXPECT_EQ(r.output.find(cut.string() + ": " + cut.string()), std::string::npos) << r.output;
  for (const fs::path& f : {text, empty, cut}) fs::remove(f);
}

// A file that is not a database, given to the commands that open one through the reader: refused,
// unchanged, its name said once (precompute and bench nearest said "x.db: x.db is not ...").
TEST(HostileInputs, NotADatabaseIsNamedOnceAndLeftAlone) {
  const fs::path text = work_dir() / "notes.clothdb";
  std::ofstream(text) << "hello, not a database\n";
  const std::string scene = scene_with("not_a_db", "");
  const std::vector<std::vector<std::string>> commands = {
      {"precompute", scene, "--db", text.string(), "--no-floor", "--quiet"},
      {"bench", "nearest", "--db", text.string()},
      {"db", "info", text.string()},
      {"clips", "list", text.string()},
      {"play", text.string(), "--out", (work_dir() / "p").string()}};
  for (const auto& args : commands) {
    expect_refused(args, {text.string() + " is not a clothdb database (not even SQLite)"});
    const Result r = clothdb(args);
    EXPECT_EQ(r.output.find(text.string() + ": " + text.string()), std::string::npos) << r.output;
  }
  fs::remove(text);
  fs::remove(scene);
}

TEST(HostileInputs, DirectoriesAreReportedAsDirectories) {
  const fs::path dir = work_dir() / "a_directory";
  fs::create_directories(dir);
  expect_refused({"db", "check", dir.string()}, {dir.string(), "is a directory"});
  expect_refused({"play", dir.string(), "--out", (work_dir() / "x").string(), "--seconds", "1"},
                 {"is a directory"});
  expect_refused({"simulate", dir.string(), "--out", (work_dir() / "x").string()},
                 {dir.string() + ": is a directory, not a scene file"});
  const std::string scene = (work_dir() / "dir_manifest.json").string();
  std::ofstream(scene) << R"({"manifest": ")" << dir.string()
                       << R"(", "garment": {"type": "skirt"}})";
  expect_refused({"simulate", scene, "--out", (work_dir() / "x").string()},
                 {dir.string() + ": is a directory, not a manifest file"});
  fs::remove(scene);
  fs::remove(dir);
}

// The work directory goes when the tests are done.
struct RemoveWorkDir : testing::Environment {
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(work_dir(), ec);
  }
};
const auto* const kRemoveWorkDir = testing::AddGlobalTestEnvironment(new RemoveWorkDir);

}  // namespace

// A garment modelled on a posed frame (here: the character standing on the floor, its hips 0.95 m
// above the rest pose's) is refused before anything is simulated or written, naming the scene
// file, the field, the pins' distance and the likely cause (docs/guide/garment_placement.md).
TEST(HostileInputs, PosedGarmentIsRefusedWithItsDistance) {
  std::string obj;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 8; ++c) {
      const double a = 2 * 3.14159265358979 * c / 8;
      obj += "v " + std::to_string(0.14 * std::cos(a)) + " " + std::to_string(0.95 - 0.1 * r) +
             " " + std::to_string(0.14 * std::sin(a)) + "\n";
    }
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 8; ++c) {
      const int a = r * 8 + c + 1, b = r * 8 + (c + 1) % 8 + 1;
      obj += "f " + std::to_string(a) + " " + std::to_string(a + 8) + " " + std::to_string(b + 8) +
             " " + std::to_string(b) + "\n";
    }
  const std::string mesh = (work_dir() / "posed.obj").string();
  std::ofstream(mesh) << obj;
  const std::string scene = (work_dir() / "posed.json").string();
  std::ofstream(scene) << R"({"manifest": ")" << kSource << R"(/motions/cmu_walk.json",
    "clips": ["01_03_level_walk"],
    "garment": {"type": "mesh", "file": ")"
                       << mesh << R"(", "bone": "Hips", "pins": {"height_band": [0.94, 0.96]}}})";
  const std::string out = (work_dir() / "posed_out").string();
  expect_refused({"simulate", scene, "--out", out},
                 {scene + ": garment.file (" + mesh + ")", "8 pins on 'Hips' up to 0.",
                  "refused over 0.200 m", "Likely cause: modelled on a posed frame"});
  EXPECT_FALSE(fs::exists(out));
}
