// `clothdb forecast CURVE.csv...`: the explorer's forecast (explore/forecast.hpp) replayed from
// the curves a run wrote (`precompute --curve`), at chosen shares of the run, against the CPU time
// the run took: how a forecast is checked, and how a curve written by an older model is
// re-derived with the current one.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "cli_util.hpp"
#include "commands.hpp"
#include "explore/explorer.hpp"
#include "explore/forecast.hpp"

namespace clothdb::cli {

namespace {

std::string hours(double seconds) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g", seconds / 3600);
  return text;
}

}  // namespace

void register_forecast(CLI::App& app) {
  struct Args {
    std::vector<std::string> curves;
    std::vector<double> at = {0.25, 0.5, 0.75};
    std::string csv;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "forecast",
      "Replays the explorer's forecast of the CPU time to converge from the curves a run wrote "
      "(`precompute --curve PREFIX`: PREFIX.csv), made at each --at share of the run's CPU time "
      "from the curve up to there, against what the run took when it converged. Give a resumed "
      "run's curves in the order they ran");
  cmd->add_option("CURVE", args->curves, "Curve files (CSV), the first run first")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--at", args->at, "Shares of the whole run's CPU time to show the forecast at")
      ->delimiter(',')
      ->capture_default_str()
      ->check(number_in(0.0, 1.0));
  cmd->add_option("--csv", args->csv,
                  "Also write every point's forecast: cpu_hours, forecast, low and high CPU-h");
  cmd->callback([args] {
    std::vector<std::vector<CurvePoint>> runs;
    for (const std::string& path : args->curves) {
      std::ifstream in(path);
      if (!in) throw std::runtime_error(path + ": cannot open");
      runs.push_back(read_curve_csv(in, path));
    }
    const std::vector<ReplayedForecast> replayed = replay_forecasts(runs);
    const ReplayedForecast& end = replayed.back();
    const bool converged = end.forecast.converged;
    const double total = end.cpu_seconds;
    std::printf("run          %zu curve(s), %zu points, %s CPU-h, %s\n", runs.size(),
                replayed.size(), hours(total).c_str(),
                converged ? "converged"
                          : ("not converged: " + std::to_string(runs.back().back().dead_ends) +
                             " dead ends left")
                                .c_str());
    if (runs.front().front().frames != 0)
      std::printf(
          "note         %s starts with %ld frames stored: the curve of a resumed run, "
          "whose earlier runs' CPU time is not counted (give their curves first)\n",
          args->curves.front().c_str(), runs.front().front().frames);
    // A rerun of a run that had nothing left to do (the demo run again on its converged file)
    // writes a curve with no CPU time: there are no shares of it to replay.
    if (!(total > 0.0))
      std::printf(
          "at           no forecasts to replay: the curves hold no CPU time (a resumed run "
          "that had nothing left to explore; give the first run's curve too)\n");
    for (double share : total > 0.0 ? args->at : std::vector<double>{}) {
      // The point whose CPU time is nearest the share (ties: the earlier point).
      const ReplayedForecast* best = &replayed.front();
      for (const ReplayedForecast& r : replayed)
        if (std::fabs(r.cpu_seconds - share * total) < std::fabs(best->cpu_seconds - share * total))
          best = &r;
      const Forecast& f = best->forecast;
      std::string against;
      if (converged && f.converging && !f.converged) {
        char text[160];
        const bool covered = f.low_cpu_seconds <= total && total <= f.high_cpu_seconds;
        std::snprintf(text, sizeof text, "; it took %s CPU-h: %+.0f %%, %s the band",
                      hours(total).c_str(), 100 * (f.cpu_seconds - total) / total,
                      covered ? "within" : "outside");
        against = text;
      }
      std::printf("at %3.0f %%     (%s CPU-h, run %zu) %s%s\n", 100 * best->cpu_seconds / total,
                  hours(best->cpu_seconds).c_str(), best->run + 1, forecast_text(f).c_str(),
                  against.c_str());
    }
    if (!args->csv.empty()) {
      std::ofstream out(args->csv);
      out << "cpu_hours,forecast_cpu_hours,forecast_low_cpu_hours,forecast_high_cpu_hours\n";
      for (const ReplayedForecast& r : replayed) {
        out << r.cpu_seconds / 3600 << ',';
        if (r.forecast.converging)
          out << r.forecast.cpu_seconds / 3600 << ',' << r.forecast.low_cpu_seconds / 3600 << ','
              << (std::isinf(r.forecast.high_cpu_seconds)
                      ? std::string("inf")
                      : std::to_string(r.forecast.high_cpu_seconds / 3600));
        else
          out << ",,";
        out << '\n';
      }
      if (!out) throw std::runtime_error(args->csv + ": cannot write");
    }
  });
}

}  // namespace clothdb::cli
