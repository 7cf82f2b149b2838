// `clothdb db recode` (docs/DATABASE.md, "clothdb db recode"): a database recoded to codec
// version 2 checks, keeps every coordinate within the bound of the frames it had, and plays; a
// recode killed after any batch (the process ends without unwinding, as with SIGKILL) leaves a file
// that checks and plays, and a second recode finishes the job.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <Eigen/Core>
#include <chrono>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <map>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "clothrt.h"
#include "compress/recode.hpp"
#include "database/format/meta_keys.hpp"
#include "database/store/basis_store.hpp"
#include "database/store/check.hpp"
#include "database/store/writer.hpp"
#include "runtime/tools/synthetic_db.hpp"
#include "support/temp_dir.hpp"

namespace clothdb {
namespace {

namespace fs = std::filesystem;

using test::TempDir;

synthetic::Spec spec() {
  synthetic::Spec s;
  s.side = 14;
  s.nodes = 2;
  s.edges = {{0, 1, 20}, {1, 0, 24}, {1, 1, 16}};
  s.states_per_node = 3;
  return s;
}

// Every clip's and state's frames, decoded (codec version 1 or 2).
struct Contents {
  std::map<int64_t, std::vector<float>> clips, positions, velocities;
};

Contents read_all(const std::string& path) {
  db::Reader r;
  db::Error err;
  EXPECT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  Contents c;
  std::vector<db::ClothClip> clips;
  std::vector<db::StoredState> states;
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_states(&states, &err), clothdb::Status::Ok);
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob;
  for (const auto& clip : clips) {
    EXPECT_EQ(r.clip_blob(clip.id, &blob, &err), db::Status::Ok);
    EXPECT_EQ(r.decode_all(blob, &c.clips[clip.id], scratch, &err), db::Status::Ok) << err.message;
  }
  for (const auto& s : states)
    EXPECT_EQ(r.read_state(s.id, &c.positions[s.id], &c.velocities[s.id], scratch, &err),
              db::Status::Ok)
        << err.message;
  return c;
}

double max_difference(const std::map<int64_t, std::vector<float>>& a,
                      const std::map<int64_t, std::vector<float>>& b) {
  double m = 0;
  EXPECT_EQ(a.size(), b.size());
  for (const auto& [id, x] : a) {
    const auto& y = b.at(id);
    EXPECT_EQ(x.size(), y.size());
    for (size_t i = 0; i < std::min(x.size(), y.size()); ++i)
      m = std::max(m, std::fabs(double(x[i]) - double(y[i])));
  }
  return m;
}

// Opens the file with the runtime and plays `frames` frames from the start clip.
void expect_plays(const std::string& path, int frames) {
  clothrt_db* db = nullptr;
  clothrt_db_options o;
  clothrt_db_options_init(&o);
  ASSERT_EQ(clothrt_db_open(path.c_str(), &o, &db), CLOTHRT_OK) << clothrt_last_open_errmsg();
  clothrt_player* p = nullptr;
  ASSERT_EQ(clothrt_player_create(db, &p), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_start(p, clothrt_db_start_clip(db)), CLOTHRT_OK)
      << clothrt_player_errmsg(p);
  std::vector<float> x(size_t(clothrt_db_vertex_count(db)) * 3);
  for (int f = 0; f < frames; ++f) {
    ASSERT_EQ(clothrt_player_advance(p, 1.0 / 30), CLOTHRT_OK) << clothrt_player_errmsg(p);
    ASSERT_EQ(clothrt_player_get_positions(p, x.data(), 12, nullptr), CLOTHRT_OK);
    for (float v : x) ASSERT_TRUE(std::isfinite(v));
  }
  clothrt_player_destroy(p);
  clothrt_db_close(db);
}

// The positions a player shows over `frames` frames from the start clip (frame-major).
std::vector<float> played(const std::string& path, int frames) {
  clothrt_db* db = nullptr;
  EXPECT_EQ(clothrt_db_open(path.c_str(), nullptr, &db), CLOTHRT_OK) << clothrt_last_open_errmsg();
  clothrt_player* p = nullptr;
  EXPECT_EQ(clothrt_player_create(db, &p), CLOTHRT_OK);
  EXPECT_EQ(clothrt_player_start(p, clothrt_db_start_clip(db)), CLOTHRT_OK);
  const size_t n = size_t(clothrt_db_vertex_count(db)) * 3;
  std::vector<float> out(n * size_t(frames));
  for (int f = 0; f < frames; ++f) {
    EXPECT_EQ(clothrt_player_advance(p, 1.0 / 30), CLOTHRT_OK) << clothrt_player_errmsg(p);
    EXPECT_EQ(clothrt_player_get_positions(p, out.data() + n * size_t(f), 12, nullptr), CLOTHRT_OK);
  }
  clothrt_player_destroy(p);
  clothrt_db_close(db);
  return out;
}

void expect_checks(const std::string& path) {
  const db::CheckReport report = db::check_database(path);
  for (const auto& p : report.problems) ADD_FAILURE() << p;
  EXPECT_GT(report.blobs_checked, 0u);
}

RecodeOptions options(double bound) {
  RecodeOptions o;
  o.bound = bound;
  o.velocity_bound = 0.002;
  o.modes = 12;
  o.batch = 4;
  return o;
}

TEST(Recode, V2KeepsTheBoundChecksAndPlays) {
  TempDir dir;
  const std::string path = dir.file("sheet.db");
  synthetic::build(path, spec());
  const Contents before = read_all(path);
  // Progress says how far it is and, until the last line, the time left.
  std::vector<std::string> lines;
  RecodeOptions o = options(0.0005);
  o.batch = 1;  // a progress line every 8 batches
  o.progress = [&](const std::string& line) { lines.push_back(line); };
  const RecodeReport r = recode_database(path, o);
  std::vector<std::string> rows_lines;
  for (const std::string& l : lines)
    if (l.rfind("recoded ", 0) == 0) rows_lines.push_back(l);
  ASSERT_GE(rows_lines.size(), 2u) << "too few batches for a progress line before the last";
  EXPECT_NE(rows_lines.front().find(" s left"), std::string::npos) << rows_lines.front();
  EXPECT_EQ(rows_lines.back().find("left"), std::string::npos) << rows_lines.back();
  EXPECT_GT(r.basis_id, 0);
  EXPECT_GT(r.clips_replaced, 0u);
  EXPECT_LE(r.blob_bytes_after, r.blob_bytes_before);
  const db::DatabaseInfo info = db::read_database_info(path);
  EXPECT_EQ(info.clips_v2, r.clips_replaced);
  EXPECT_EQ(info.clips_v1 + info.clips_v2, info.cloth_clips);
  ASSERT_EQ(info.bases.size(), 1u);
  const Contents after = read_all(path);
  EXPECT_LE(max_difference(before.clips, after.clips), 0.0005);
  EXPECT_LE(max_difference(before.positions, after.positions), 0.0005);
  EXPECT_LE(max_difference(before.velocities, after.velocities), 0.002);
  // The recorded bound is the old one plus the recode's; the check verifies every clip within it.
  db::Reader reader;
  db::Error err;
  ASSERT_EQ(reader.open(path, &err), db::Status::Ok);
  std::vector<db::ClothClip> clips;
  EXPECT_EQ(reader.cloth_clips(&clips, &err), clothdb::Status::Ok);
  for (const auto& c : clips) {
    EXPECT_LE(c.max_error, c.error_bound);
    EXPECT_NEAR(c.error_bound, 0.0005 + db::CodecSettings{}.position_bound, 1e-12);
  }
  expect_checks(path);
  expect_plays(path, 120);
}

TEST(Recode, KilledAtAnyBatchLeavesAFileThatChecksAndPlays) {
  TempDir dir;
  const std::string original = dir.file("original.db");
  synthetic::build(original, spec());
  const Contents before = read_all(original);
  const size_t rows = before.clips.size() + before.positions.size();
  const uint64_t batches = (rows + 3) / 4;
  for (uint64_t kill_after : {uint64_t(0), uint64_t(1), batches / 2, batches - 1}) {
    SCOPED_TRACE("killed after batch " + std::to_string(kill_after));
    const std::string path = dir.file("killed" + std::to_string(kill_after) + ".db");
    fs::copy_file(original, path);
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      // OpenMP's thread pool does not survive fork(): the child builds its basis on one thread.
      Eigen::setNbThreads(1);
      RecodeOptions o = options(0.0005);
      // 0: killed while the basis is built, before any batch.
      if (kill_after == 0) o.progress = [](const std::string&) { _exit(0); };
      o.after_batch = [kill_after](uint64_t done) {
        if (done == kill_after) _exit(0);  // no destructors, no rollback: as a kill
      };
      try {
        recode_database(path, o);
      } catch (...) {
        _exit(2);
      }
      _exit(3);  // should have been killed
    }
    int status = 0;
    ASSERT_EQ(waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFEXITED(status));
    ASSERT_EQ(WEXITSTATUS(status), 0);
    expect_checks(path);
    expect_plays(path, 90);
    const Contents partial = read_all(path);
    EXPECT_LE(max_difference(before.clips, partial.clips), 0.0005);
    EXPECT_LE(max_difference(before.positions, partial.positions), 0.0005);
    const db::DatabaseInfo info = db::read_database_info(path);
    if (kill_after > 0) {
      EXPECT_GT(info.clips_v2, 0u);
    }
    EXPECT_LT(info.clips_v2 + info.states_v2, info.cloth_clips + info.cloth_states);
    // Running the recode again finishes it (a new basis; blobs of the old one decode still).
    recode_database(path, options(0.0005));
    expect_checks(path);
    expect_plays(path, 60);
  }
}

// The same with a real SIGKILL at moments spread over a whole recode (within a batch's
// statements, during a commit, during the final VACUUM): SQLite's journal must leave each file
// with every blob either the old or the new one. One row per transaction, so most moments fall
// inside one. Kills follow a count of committed batches the recode reports, spread over the whole
// run; where exactly within the next batch each lands varies, and the property must hold wherever.
TEST(Recode, SigkillAtAnyMomentLeavesAFileThatChecksAndPlays) {
  TempDir dir;
  const std::string original = dir.file("original.db");
  synthetic::build(original, spec());
  const Contents before = read_all(original);
  // Forks a recode of `path` that reports each committed batch on a pipe; kills it as soon as it
  // has reported `kill_after` (< 0: lets it finish), so a committed-batch count, not a sleep,
  // decides where the kill lands (the child carries on with the next batch meanwhile). Returns
  // the batches it reported.
  auto recode_in_child = [](const std::string& path, int kill_after, bool* killed) {
    int fds[2];
    if (pipe(fds) != 0) return -1;
    const pid_t child = fork();
    if (child == 0) {
      close(fds[0]);
      Eigen::setNbThreads(1);  // OpenMP's thread pool does not survive fork()
      RecodeOptions o = options(0.0005);
      o.batch = 1;
      o.after_batch = [fd = fds[1]](uint64_t batches) {
        const int32_t n = static_cast<int32_t>(batches);
        if (write(fd, &n, sizeof n) != sizeof n) _exit(4);
      };
      try {
        recode_database(path, o);
      } catch (...) {
        _exit(2);
      }
      _exit(0);
    }
    close(fds[1]);
    if (child < 0) return -1;
    int reported = 0;
    int32_t n = 0;
    while ((kill_after < 0 || reported < kill_after) && read(fds[0], &n, sizeof n) == sizeof n)
      reported = n;
    if (kill_after >= 0) kill(child, SIGKILL);
    while (read(fds[0], &n, sizeof n) == sizeof n) reported = n;
    close(fds[0]);
    int status = 0;
    waitpid(child, &status, 0);
    *killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
    if (!*killed) {
      EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    }
    return reported;
  };
  bool killed = false;
  const std::string whole = dir.file("whole.db");
  fs::copy_file(original, whole);
  const int batches = recode_in_child(whole, -1, &killed);
  ASSERT_GE(batches, 10) << "too few batches to kill the recode at spread moments";
  int kills = 0;
  for (int k = 1; k <= 9; ++k) {
    const int after = batches * k / 10;
    SCOPED_TRACE("SIGKILL after " + std::to_string(after) + " of " + std::to_string(batches) +
                 " batches");
    const std::string path = dir.file("sigkill" + std::to_string(k) + ".db");
    fs::copy_file(original, path);
    recode_in_child(path, after, &killed);
    kills += killed;
    expect_checks(path);
    expect_plays(path, 60);
    const Contents partial = read_all(path);
    EXPECT_LE(max_difference(before.clips, partial.clips), 0.0005);
    EXPECT_LE(max_difference(before.positions, partial.positions), 0.0005);
    EXPECT_LE(max_difference(before.velocities, partial.velocities), 0.002);
  }
  EXPECT_GT(kills, 0) << "every recode finished before its kill: nothing was tested";
}

// The runtime loads a database's basis once, at open, and counts it in the memory it reports
// (one player's memory includes the basis: docs/RESULTS.md#runtime-playback-cost-and-memory);
// players share it.
TEST(Recode, RuntimeCountsTheBasisOnceInItsMemory) {
  TempDir dir;
  const std::string v1 = dir.file("v1.db"), v2 = dir.file("v2.db");
  synthetic::build(v1, spec());
  fs::copy_file(v1, v2);
  RecodeOptions o = options(0.0005);
  o.always = true;
  recode_database(v2, o);
  const db::DatabaseInfo info = db::read_database_info(v2);
  ASSERT_EQ(info.bases.size(), 1u);
  const size_t coordinates = size_t(info.garment_vertices) * 3;
  const size_t basis_floats =
      coordinates + info.bases[0].mode_count + size_t(info.bases[0].mode_count) * coordinates;
  auto metadata = [](const std::string& path, int players) {
    clothrt_db* db = nullptr;
    EXPECT_EQ(clothrt_db_open(path.c_str(), nullptr, &db), CLOTHRT_OK);
    std::vector<clothrt_player*> p(size_t(players), nullptr);
    for (auto& player : p) {
      EXPECT_EQ(clothrt_player_create(db, &player), CLOTHRT_OK);
      EXPECT_EQ(clothrt_player_start(player, clothrt_db_start_clip(db)), CLOTHRT_OK);
      EXPECT_EQ(clothrt_player_advance(player, 0.5), CLOTHRT_OK) << clothrt_player_errmsg(player);
    }
    clothrt_stats s{};
    EXPECT_EQ(clothrt_db_stats(db, &s), CLOTHRT_OK);
    for (auto* player : p) clothrt_player_destroy(player);
    clothrt_db_close(db);
    return s.metadata_bytes;
  };
  const size_t without = metadata(v1, 1), with = metadata(v2, 1);
  EXPECT_GE(with, without + basis_floats * sizeof(float));
  EXPECT_LT(with, without + basis_floats * sizeof(float) + 4096);
  EXPECT_EQ(metadata(v2, 3), with);  // three players, one basis
}

TEST(Recode, V1AtALargerBoundAlsoWorks) {
  TempDir dir;
  const std::string path = dir.file("v1.db");
  synthetic::build(path, spec());
  const Contents before = read_all(path);
  RecodeOptions o = options(0.002);
  o.codec = 1;
  const RecodeReport r = recode_database(path, o);
  EXPECT_EQ(r.basis_id, 0);
  EXPECT_LT(r.blob_bytes_after, r.blob_bytes_before);
  EXPECT_LE(max_difference(before.clips, read_all(path).clips), 0.002);
  EXPECT_EQ(db::read_database_info(path).clips_v2, 0u);
  expect_checks(path);
  expect_plays(path, 60);
}

}  // namespace
}  // namespace clothdb

// ---- codec version 3: the error contract (docs/DATABASE.md, "The error contract") ------------

namespace clothdb {
namespace {

RecodeOptions v3_options() {
  RecodeOptions o;
  o.codec = 3;
  o.contract = {0.001, 0.003, 0.0001};
  o.modes = 12;
  o.batch = 4;
  o.always = true;  // the synthetic clips are small: measure the contract on every one
  return o;
}

// Each clip of `after` against the same clip of `before`, within the contract's caps.
void expect_within_contract(const Contents& before, const Contents& after,
                            const codec::Contract& caps, uint32_t vertices) {
  ASSERT_EQ(before.clips.size(), after.clips.size());
  for (const auto& [id, x] : before.clips) {
    const auto& y = after.clips.at(id);
    ASSERT_EQ(x.size(), y.size());
    const auto m = codec::measure_contract(y.data(), x.data(),
                                           uint32_t(x.size() / (size_t(vertices) * 3)), vertices);
    EXPECT_TRUE(codec::within(m, caps)) << "clip " << id << ": " << codec::describe(m);
  }
}

TEST(RecodeV3, EveryClipWithinItsCapsChecksAndPlays) {
  TempDir dir;
  const std::string path = dir.file("v3.db");
  synthetic::build(path, spec());
  const Contents before = read_all(path);
  const std::vector<float> shown_before = played(path, 90);
  const RecodeReport r = recode_database(path, v3_options());
  EXPECT_EQ(r.clips_replaced, r.clips);
  EXPECT_EQ(r.states_replaced, 0u) << "states keep the strict bound";
  // What a player shows moves by no more than the max cap (the same walk: the graph and the
  // states are unchanged; blends are convex combinations of frames each within the cap).
  const std::vector<float> shown_after = played(path, 90);
  ASSERT_EQ(shown_before.size(), shown_after.size());
  double worst = 0;
  for (size_t i = 0; i + 2 < shown_before.size(); i += 3) {
    double d2 = 0;
    for (size_t a = 0; a < 3; ++a) {
      const double d = double(shown_after[i + a]) - double(shown_before[i + a]);
      d2 += d * d;
    }
    worst = std::max(worst, std::sqrt(d2));
  }
  EXPECT_LE(worst, v3_options().contract.max * (1 + 1e-3));
  const uint32_t V = uint32_t(spec().side * spec().side);
  expect_within_contract(before, read_all(path), v3_options().contract, V);
  expect_checks(path);
  expect_plays(path, 90);
  const db::DatabaseInfo info = db::read_database_info(path);
  EXPECT_EQ(info.clips_v3, info.cloth_clips);
  EXPECT_EQ(info.contracts, info.cloth_clips);
  EXPECT_TRUE(codec::within(info.worst_contract, v3_options().contract));
  db::Reader reader;
  db::Error err;
  ASSERT_EQ(reader.open(path, &err), db::Status::Ok);
  std::string version;
  ASSERT_EQ(reader.meta(db::meta::kCodecFormatVersion, &version, &err), db::Status::Ok);
  EXPECT_EQ(version, "3");
}

TEST(RecodeV3, CheckRefusesFiguresBeyondTheCapsAndMissingContracts) {
  TempDir dir;
  const std::string path = dir.file("v3.db");
  synthetic::build(path, spec());
  recode_database(path, v3_options());
  auto problems_after = [&](const std::string& sql) {
    const std::string copy = dir.file("damaged.db");
    fs::remove(copy);
    fs::copy_file(path, copy);
    {
      db::Writer w = db::Writer::open(copy);
      EXPECT_EQ(sqlite3_exec(w.handle(), sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK);
    }
    return db::check_database(copy).problems;
  };
  auto mentions = [](const std::vector<std::string>& problems, const std::string& words) {
    for (const auto& p : problems)
      if (p.find(words) != std::string::npos) return true;
    return false;
  };
  EXPECT_TRUE(mentions(problems_after("UPDATE codec_contract SET jitter = 0.0002 WHERE clip = "
                                      "(SELECT min(clip) FROM codec_contract);"),
                       "exceeds its caps"));
  EXPECT_TRUE(mentions(problems_after("DELETE FROM codec_contract WHERE clip = "
                                      "(SELECT min(clip) FROM codec_contract);"),
                       "without a codec_contract row"));
  // A damaged blob: refused by its checksum.
  EXPECT_TRUE(mentions(problems_after("UPDATE cloth_clip SET frames = substr(frames, 1, 90) || "
                                      "x'00' || substr(frames, 92) WHERE id = (SELECT min(id) "
                                      "FROM cloth_clip);"),
                       "checksum"));
}

TEST(RecodeV3, KilledAfterAnyBatchLeavesAFileThatChecksPlaysAndFinishes) {
  TempDir dir;
  const std::string original = dir.file("original.db");
  synthetic::build(original, spec());
  const Contents before = read_all(original);
  const uint32_t V = uint32_t(spec().side * spec().side);
  const uint64_t batches = (before.clips.size() + 3) / 4;  // states are not rewritten
  ASSERT_GE(batches, 3u);
  for (uint64_t kill_after : {uint64_t(1), batches - 1}) {
    SCOPED_TRACE("killed after batch " + std::to_string(kill_after));
    const std::string path = dir.file("killed" + std::to_string(kill_after) + ".db");
    fs::copy_file(original, path);
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      Eigen::setNbThreads(1);  // OpenMP's thread pool does not survive fork()
      RecodeOptions o = v3_options();
      o.after_batch = [kill_after](uint64_t done) {
        if (done == kill_after) _exit(0);  // no destructors, no rollback: as a kill
      };
      try {
        recode_database(path, o);
      } catch (...) {
        _exit(2);
      }
      _exit(3);
    }
    int status = 0;
    ASSERT_EQ(waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFEXITED(status));
    ASSERT_EQ(WEXITSTATUS(status), 0);
    expect_checks(path);
    expect_plays(path, 60);
    const db::DatabaseInfo partial = db::read_database_info(path);
    EXPECT_GT(partial.clips_v3, 0u);
    EXPECT_LT(partial.clips_v3, partial.cloth_clips);
    // Running it again finishes: the clips already of version 3 are kept, the rest recoded.
    const RecodeReport r = recode_database(path, v3_options());
    EXPECT_EQ(r.clips_already_v3, partial.clips_v3);
    expect_checks(path);
    expect_plays(path, 60);
    expect_within_contract(before, read_all(path), v3_options().contract, V);
    EXPECT_EQ(db::read_database_info(path).clips_v3, partial.cloth_clips);
  }
}

}  // namespace
}  // namespace clothdb
