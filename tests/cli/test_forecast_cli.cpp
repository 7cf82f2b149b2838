// `clothdb forecast` (cli/cmd_forecast.cpp) on the committed curves of the whole-motion run, a run
// and its resume (docs/results/whole_motion/): the replayed forecasts at chosen shares of the run,
// the band against the CPU time the run took, the points' CSV, and the refusals.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "support/cli.hpp"
#include "support/temp_dir.hpp"

using namespace clothdb::test;

namespace {

const std::string kCurves = std::string(CLOTHDB_SOURCE_DIR) + "/docs/results/whole_motion/";

}  // namespace

TEST(ForecastCli, ReplaysARunAndItsResumeAgainstWhatItTook) {
  TempDir dir;
  const std::string log = dir.file("log.txt"), csv = dir.file("points.csv");
  const CliResult r =
      run_clothdb({"forecast", kCurves + "error_curve_run1.csv", kCurves + "error_curve_run2.csv",
                   "--at", "0.1,0.5,0.75", "--csv", csv},
                  log);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("2 curve(s)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("converged"), std::string::npos) << r.output;
  // Three lines, one per share; early in the run the open ways out still rise: none.
  EXPECT_NE(r.output.find("at  10 %"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("none: not converging"), std::string::npos) << r.output;
  // Later, a forecast with its band and the comparison with the CPU time it took.
  EXPECT_NE(r.output.find("CPU-h to converge"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("; it took 0.403 CPU-h: "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(" the band"), std::string::npos) << r.output;
  // One CSV row per curve point (46 + 53 = 99 points) after the header.
  const std::string points = read_text(csv);
  size_t rows = 0;
  for (char c : points) rows += c == '\n';
  EXPECT_EQ(rows, 1u + 99u) << points.substr(0, 200);
}

TEST(ForecastCli, RefusesCurvesOutOfOrderAndAFileThatIsNotACurve) {
  TempDir dir;
  const std::string log = dir.file("log.txt");
  const CliResult swapped = run_clothdb(
      {"forecast", kCurves + "error_curve_run2.csv", kCurves + "error_curve_run1.csv"}, log);
  EXPECT_EQ(swapped.code, 1) << swapped.output;
  EXPECT_NE(swapped.output.find("not a resume of it"), std::string::npos) << swapped.output;
  const std::string bad = dir.file("bad.csv");
  std::ofstream(bad) << "cpu_seconds,frames\n0,0\n";
  const CliResult not_curve = run_clothdb({"forecast", bad}, log);
  EXPECT_EQ(not_curve.code, 1) << not_curve.output;
  EXPECT_NE(not_curve.output.find(bad + ": no column 'states'"), std::string::npos)
      << not_curve.output;
}

// A rerun of a converged run (the demo's second run) writes a one-point curve with no CPU time:
// no shares of it to replay, said in words rather than as "at -nan %".
TEST(ForecastCli, SaysSoWhenTheCurveHoldsNoCpuTime) {
  TempDir dir;
  const std::string log = dir.file("log.txt"), curve = dir.file("rerun.csv");
  std::ofstream(curve)
      << "cpu_seconds,frames,states,dead_ends,unexplored,worst_error_mm,weighted_worst_error_mm,"
         "mean_error_mm,linked_percent,forecast_cpu_hours,forecast_low_cpu_hours,"
         "forecast_high_cpu_hours,clips\n"
         "0,1782,53,0,0,0,0,0,24.6377,0.0289207,0.0289207,0.0289207,69\n";
  const CliResult r = run_clothdb({"forecast", curve, "--at", "0.25,0.5"}, log);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_EQ(r.output.find("nan"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no forecasts to replay"), std::string::npos) << r.output;
}
