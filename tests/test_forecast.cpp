// The explorer's forecast of the CPU time to converge (explore/forecast.hpp), on synthetic curves:
// it refuses a trend that does not fall, forecasts a finite time for a falling one (and the time
// the model gives), and reports a converged run as what it took.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "explore/forecast.hpp"

using namespace clothdb;

namespace {

// A curve of `points` batches over `seconds` of CPU time whose dead ends follow dead_ends(t).
template <typename F>
std::vector<CurvePoint> curve(int points, double seconds, F dead_ends) {
  std::vector<CurvePoint> out;
  for (int k = 0; k <= points; ++k) {
    CurvePoint p;
    p.cpu_seconds = seconds * k / points;
    p.dead_ends = static_cast<int>(std::lround(dead_ends(p.cpu_seconds)));
    out.push_back(p);
  }
  return out;
}

}  // namespace

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
  EXPECT_NE(text.find(" CPU-h to converge (model linear decline"), std::string::npos) << text;
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
