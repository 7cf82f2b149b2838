// The explorer's forecast of the CPU time to converge (explore/forecast.hpp), on synthetic curves:
// it refuses a trend that does not fall (rising, flat, or rising ever more slowly), forecasts a
// finite time for a falling one (and the time the model gives), recovers the end of a branching
// process whose share of linked clip ends climbs (the demo's shape) from half of it, and reports a
// converged run as what it took.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <string>

#include "explore/explorer.hpp"
#include "explore/forecast.hpp"
#include "explore/progress.hpp"

using namespace clothdb;

namespace {

// Clips per batch of the synthetic curves (precompute's default --batch), each as costly as the
// next: clips and CPU time grow together.
constexpr long kBatch = 16;

// A curve of `points` batches over `seconds` of CPU time whose dead ends follow dead_ends(t).
template <typename F>
std::vector<CurvePoint> curve(int points, double seconds, F dead_ends) {
  std::vector<CurvePoint> out;
  for (int k = 0; k <= points; ++k) {
    CurvePoint p;
    p.cpu_seconds = seconds * k / points;
    p.clips = kBatch * k;
    p.dead_ends = static_cast<int>(std::lround(dead_ends(p.cpu_seconds)));
    out.push_back(p);
  }
  return out;
}

}  // namespace

// A branching process's curve: open ways out falling by `rate` per CPU-s from `start` with
// independent Gaussian scatter of `sigma` per batch, rounded to whole dead ends; ends at 0.
std::vector<CurvePoint> noisy_decline(double start, double rate, double sigma, double batch_s,
                                      double until_s, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, sigma);
  std::vector<CurvePoint> out;
  for (double t = 0; t <= until_s; t += batch_s) {
    CurvePoint p;
    p.cpu_seconds = t;
    p.clips = kBatch * static_cast<long>(out.size());
    p.dead_ends = static_cast<int>(std::max(1.0, std::round(start - rate * t + noise(rng))));
    out.push_back(p);
  }
  return out;
}

TEST(Forecast, RefusesARisingTrend) {
  const auto rising = curve(40, 600, [](double t) { return 10 + t / 5; });
  const Forecast f = forecast_convergence(rising, 0);
  EXPECT_FALSE(f.converging);
  EXPECT_FALSE(f.too_few);
  const std::string text = forecast_text(f);
  EXPECT_EQ(text.rfind("none: not converging (", 0), 0u) << text;
}

TEST(Forecast, RefusesAFlatTrend) {
  const auto flat = curve(40, 600, [](double) { return 50; });
  EXPECT_FALSE(forecast_convergence(flat, 0).converging);
}

TEST(Forecast, RefusesATrendThatRisesEverMoreSlowly) {
  // Bending down but still rising at the last batch: the process is not yet subcritical, so no
  // forecast, however the bend would extrapolate.
  for (double made_at : {200.0, 600.0, 2000.0}) {
    const auto slowing = curve(40, made_at, [](double t) { return 10 * std::sqrt(t); });
    const Forecast f = forecast_convergence(slowing, 0);
    EXPECT_FALSE(f.converging) << made_at << ": " << forecast_text(f);
    EXPECT_EQ(forecast_text(f).rfind("none: not converging (", 0), 0u);
  }
}

// A branching process run a clip at a time (Kim et al.'s exploration): each clip closes one way
// out; its end links with probability p (it makes no state), else it makes a state with `ways`
// ways out. p climbs linearly from p0 by dp per clip (its nodes gain states to link to). The
// expected curve, one point per batch of kBatch clips and `clip_s` CPU-s per clip, until no way
// out is left; *end_s is the CPU time that happens.
std::vector<CurvePoint> branching(double ways, double p0, double dp, double clip_s, double* end_s) {
  std::vector<CurvePoint> out;
  double y = 1;
  long clips = 0;
  for (;; ++clips) {
    if (clips % kBatch == 0 || y <= 0) {
      CurvePoint p;
      p.clips = clips;
      p.cpu_seconds = clip_s * static_cast<double>(clips);
      p.dead_ends = static_cast<int>(std::ceil(std::max(0.0, y)));
      out.push_back(p);
    }
    if (y <= 0) break;
    const double p = std::min(1.0, p0 + dp * static_cast<double>(clips));
    y += ways * (1 - p) - 1;
  }
  *end_s = out.back().cpu_seconds;
  return out;
}

TEST(Forecast, RecoversTheEndOfABranchingProcessWhoseLinkedShareClimbs) {
  // The demo's shape: 1.3 ways out per state, the share of clip ends linked climbing from 5 % by
  // 0.05 to 0.2 % per clip, so the open ways out rise, peak about half way, then fall ever faster.
  // Before the peak there is no forecast (the trend still rises); from two batches after it on, the
  // forecast is within 30 % of the end, which lies within its band (to a batch: the curve is
  // rounded to whole ways out and sampled per batch).
  const double ways = 1.3, p0 = 0.05, clip_s = 1.5;
  for (double dp : {0.0005, 0.001, 0.002}) {
    double end = 0;
    const auto run = branching(ways, p0, dp, clip_s, &end);
    ASSERT_GT(run.size(), 6u) << dp;
    const double slack = kBatch * clip_s;
    int forecasts = 0;
    for (size_t k = 1; k + 1 < run.size(); ++k) {
      const std::vector<CurvePoint> so_far(run.begin(), run.begin() + static_cast<long>(k) + 1);
      const Forecast f = forecast_convergence(so_far, 0);
      const double clips = static_cast<double>(so_far.back().clips);
      const double change_per_clip = ways * (1 - std::min(1.0, p0 + dp * clips)) - 1;
      if (change_per_clip > 0) {
        EXPECT_FALSE(f.converging)
            << "dp " << dp << " at clip " << clips << ": " << forecast_text(f);
      } else if (change_per_clip < -2 * ways * dp * kBatch) {
        ASSERT_TRUE(f.converging) << "dp " << dp << " at clip " << clips << ": " << f.why;
        ++forecasts;
        EXPECT_NEAR(f.cpu_seconds, end, 0.3 * end) << "dp " << dp << " at clip " << clips;
        EXPECT_LE(f.low_cpu_seconds, end + slack) << "dp " << dp << " at clip " << clips;
        EXPECT_GE(f.high_cpu_seconds, end - slack) << "dp " << dp << " at clip " << clips;
      }
    }
    EXPECT_GE(forecasts, 2) << dp;
  }
}

TEST(Forecast, FallingTrendGivesTheTimeTheLineReachesZero) {
  // 400 - 0.3 (t - 300 s) after a rise to 400 at 300 s: zero at 300 s + 400 / 0.3 = 1633 s.
  // Rounding to whole dead ends moves it a little; the rise in the first half (new nodes reached)
  // must not matter.
  const double made_at = 900;
  const auto falling = curve(90, made_at, [&](double t) {
    return t < made_at / 3 ? 400 * t / (made_at / 3) : 400 - 0.3 * (t - made_at / 3);
  });
  const Forecast f = forecast_convergence(falling, 0);
  ASSERT_TRUE(f.converging) << f.why;
  EXPECT_FALSE(f.converged);
  EXPECT_TRUE(std::isfinite(f.cpu_seconds));
  const double expected = made_at / 3 + 400 / 0.3;
  EXPECT_NEAR(f.cpu_seconds, expected, 0.02 * expected);
  EXPECT_DOUBLE_EQ(f.made_at, made_at);
  const std::string text = forecast_text(f);
  EXPECT_NE(text.find(" CPU-h to converge (band "), std::string::npos) << text;
  EXPECT_NE(text.find("; model dead ends + unexplored ways out against clips made, a "),
            std::string::npos)
      << text;
  EXPECT_NE(text.find(" fewer per CPU-h"), std::string::npos) << text;
  EXPECT_NE(text.find("made at 0.25 CPU-h)"), std::string::npos) << text;
}

TEST(Forecast, EarlierRunsShiftTheForecastByTheirCpuTime) {
  const auto falling = curve(40, 600, [](double t) { return 100 * std::exp(-t / 150); });
  const Forecast alone = forecast_convergence(falling, 0),
                 resumed = forecast_convergence(falling, 3600);
  ASSERT_TRUE(alone.converging && resumed.converging);
  EXPECT_NEAR(resumed.cpu_seconds - alone.cpu_seconds, 3600, 1e-6);
  EXPECT_NEAR(resumed.made_at, 4200, 1e-9);
}

TEST(Forecast, ConvergedRunIsWhatItTook) {
  auto done = curve(10, 300, [](double t) { return t < 300 ? 5 : 0; });
  const Forecast f = forecast_convergence(done, 100);
  EXPECT_TRUE(f.converged);
  EXPECT_DOUBLE_EQ(f.cpu_seconds, 400);
}

TEST(Forecast, TooFewBatchesIsNoForecast) {
  const auto short_run = curve(3, 60, [](double t) { return 100 - t; });
  const Forecast f = forecast_convergence(short_run, 0);
  EXPECT_FALSE(f.converging);
  EXPECT_TRUE(f.too_few);
  EXPECT_EQ(forecast_text(f).rfind("none: too few batches to fit (", 0), 0u);
}

TEST(Forecast, KnownEndOfANoisyDeclineLiesWithinTheBand) {
  // 200 ways out falling by 0.2 per CPU-s: the end is at 1000 CPU-s. Forecasts made at a quarter,
  // half and three quarters of it, on 100 seeds of scatter (5 dead ends per batch of 10 CPU-s):
  // the band (the fit's 95 % prediction band) holds the end in at least 88 of 100
  // each time, and is an interval around the forecast.
  const double end = 1000;
  for (double share : {0.25, 0.5, 0.75}) {
    int covered = 0, narrow = 0;
    for (unsigned seed = 1; seed <= 100; ++seed) {
      const auto c = noisy_decline(200, 0.2, 5, 10, share * end, seed);
      const Forecast f = forecast_convergence(c, 0);
      ASSERT_TRUE(f.converging) << f.why;
      EXPECT_LE(f.low_cpu_seconds, f.cpu_seconds);
      EXPECT_GE(f.high_cpu_seconds, f.cpu_seconds);
      EXPECT_GE(f.low_cpu_seconds, f.made_at);
      // Not vacuous: from half the run on, a band narrower than the run (but where the scatter
      // happens to bend the fit clearly: then the band is the bend's, wider).
      narrow += f.high_cpu_seconds - f.low_cpu_seconds < end;
      covered += f.low_cpu_seconds <= end && end <= f.high_cpu_seconds;
    }
    if (share >= 0.5) {
      EXPECT_GE(narrow, 90) << "at " << share;
    }
    EXPECT_GE(covered, 88) << "at " << share;
  }
}

TEST(Forecast, WideBandIsPrintedAsTheBandAndAnOpenOneAsALowerEnd) {
  // Scatter as large as the fall: the band is wide (printed "L-H CPU-h to converge"), or open
  // above ("at least L CPU-h") when the fall is not clear of it.
  const Forecast wide = forecast_convergence(noisy_decline(100, 0.1, 8, 10, 400, 3), 0);
  ASSERT_TRUE(wide.converging) << wide.why;
  const std::string text = forecast_text(wide);
  if (std::isinf(wide.high_cpu_seconds))
    EXPECT_EQ(text.rfind("at least ", 0), 0u) << text;
  else
    EXPECT_NE(text.find("-"), std::string::npos) << text;
  EXPECT_NE(text.find("CPU-h to converge ("), std::string::npos) << text;
  // Linear but for the rounding to whole dead ends: a narrow band around the line's end.
  const auto exact = curve(40, 400, [](double t) { return 200 - 0.25 * t; });
  const Forecast line = forecast_convergence(exact, 0);
  ASSERT_TRUE(line.converging);
  EXPECT_NEAR(line.cpu_seconds, 800, 1);
  EXPECT_NEAR(line.low_cpu_seconds, 800, 8);
  EXPECT_NEAR(line.high_cpu_seconds, 800, 8);
  EXPECT_NE(forecast_text(line).find(" CPU-h to converge (band "), std::string::npos);
}

TEST(Forecast, NoForecastFromFewerThanFourPointsInTheLastHalf) {
  for (int points = 1; points <= 6; ++points) {
    const auto c = curve(points, 100, [](double t) { return 100 - t / 2; });
    size_t in_window = 0;
    for (const CurvePoint& p : c) in_window += p.cpu_seconds >= c.back().cpu_seconds / 2;
    const Forecast f = forecast_convergence(c, 0);
    EXPECT_EQ(f.converging, in_window >= kForecastFewestPoints) << points << " batches";
    EXPECT_EQ(f.too_few, in_window < kForecastFewestPoints) << points << " batches";
  }
}

TEST(Forecast, ReplayFromTheCsvIsWhatTheRunMade) {
  // A run and its resume, written as precompute writes them and read back: each point's replayed
  // forecast is the one made from the curve up to it, with the first run's CPU before the resume.
  auto first = curve(20, 200, [](double t) { return 300 - 0.5 * t; });
  auto second = curve(20, 200, [](double t) { return 200 - 0.4 * t; });
  for (size_t k = 0; k < first.size(); ++k) first[k].frames = 10 * static_cast<long>(k);
  for (size_t k = 0; k < second.size(); ++k)
    second[k].frames = first.back().frames + 10 * static_cast<long>(k);
  std::istringstream a(curve_csv(first)), b(curve_csv(second));
  const auto read_first = read_curve_csv(a, "a.csv"), read_second = read_curve_csv(b, "b.csv");
  ASSERT_EQ(read_first.size(), first.size());
  const auto replayed = replay_forecasts({read_first, read_second});
  ASSERT_EQ(replayed.size(), first.size() + second.size());
  std::vector<CurvePoint> so_far(second.begin(), second.begin() + 15);
  const Forecast direct = forecast_convergence(so_far, 200);
  const ReplayedForecast& r = replayed[first.size() + 14];
  EXPECT_EQ(r.run, 1u);
  EXPECT_DOUBLE_EQ(r.cpu_seconds, 200 + so_far.back().cpu_seconds);
  EXPECT_DOUBLE_EQ(r.forecast.cpu_seconds, direct.cpu_seconds);
  // Curves out of order are refused, naming the run.
  EXPECT_THROW(replay_forecasts({read_second, read_first}), std::runtime_error);
  // A bad cell names the file, line and column.
  std::istringstream bad("cpu_seconds,frames,states,dead_ends,unexplored\n0,0,1,1,1\n5,x,2,1,1\n");
  try {
    read_curve_csv(bad, "bad.csv");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv: line 3, column 'frames'"), std::string::npos)
        << e.what();
  }
}

// What a run prints and stores when every dead end is still alone at its node (the errors are
// NaN: unknown) and its last batch ran past a --frames budget: "unknown" and "budget reached",
// where `db info` showed "worst nan mm" and the progress line "budget ends in -3 s".
TEST(Forecast, ProgressAndNotesSayUnknownAndBudgetReached) {
  ExploreReport report;
  CurvePoint p;
  p.states = 9;
  p.dead_ends = p.unexplored = 4;
  p.worst_error = p.weighted_worst_error = p.mean_error = std::numeric_limits<double>::quiet_NaN();
  report.curve.push_back(p);
  report.frames = report.frames_this_run = 239;
  const std::string notes = run_notes(report, 4);
  EXPECT_EQ(notes.find("nan"), std::string::npos) << notes;
  EXPECT_NE(notes.find("unresolved error worst unknown, reach-weighted worst unknown"),
            std::string::npos)
      << notes;
  ExploreOptions options;
  options.progress = true;
  options.max_frames = 200;
  const ProgressBar bar(options);
  testing::internal::CaptureStderr();
  bar.update(report, Forecast{}, 8, 4);
  const std::string line = testing::internal::GetCapturedStderr();
  EXPECT_NE(line.find("budget reached"), std::string::npos) << line;
  EXPECT_EQ(line.find("in -"), std::string::npos) << line;
  EXPECT_EQ(line.find("nan"), std::string::npos) << line;
}
