// Small helpers shared by the command files.
#pragma once

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "database/codec/contract.hpp"
#include "database/store/writer.hpp"
#include "report/output.hpp"
#include "solvers/solver.hpp"

namespace clothdb::cli {

// A number as %g: range errors must not print DBL_MAX as 300 digits.
inline std::string fmt_g(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%g", v);
  return b;
}

// Option validators that refuse NaN and infinities (CLI::PositiveNumber lets NaN through, since
// every comparison with it is false) and print their bounds with %g. `lo_open`: lo itself is
// refused.
inline CLI::Validator number_in(double lo, double hi, bool lo_open = false) {
  std::string desc = (lo_open ? "(" : "[") + fmt_g(lo) + ", " + fmt_g(hi) + "]";
  return CLI::Validator(
      [lo, hi, lo_open, desc](std::string& in) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(in.c_str(), &end);
        if (in.empty() || !end || *end != '\0' || !std::isfinite(v) || v < lo || v > hi ||
            (lo_open && v == lo))
          return in + " is not a number in " + desc;
        return {};
      },
      "NUMBER in " + desc);
}
inline CLI::Validator positive_number(double hi = 1e12) {
  return number_in(0, hi, true);
}
inline CLI::Validator non_negative_number(double hi = 1e12) {
  return number_in(0, hi);
}

inline std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

// A comma-separated option of numbers in [low, high] (whole numbers if `whole`), or an error that
// names the option and the item, thrown before anything runs.
inline std::vector<double> number_list(const std::string& option, const std::string& text,
                                       double low, double high, bool whole) {
  std::vector<double> out;
  for (const auto& item : split_list(text)) {
    char* end = nullptr;
    const double value = std::strtod(item.c_str(), &end);
    if (end == item.c_str() || *end != '\0' || !(value >= low && value <= high) ||
        (whole && value != std::floor(value)))
      throw std::invalid_argument(option + ": '" + item + "' is not " +
                                  (whole ? "a whole number" : "a number") + " in [" + fmt_g(low) +
                                  ", " + fmt_g(high) + "]");
    out.push_back(value);
  }
  if (out.empty()) throw std::invalid_argument(option + ": no value given");
  return out;
}

// A command group (`clip`, `clips`, ...) that several command files add subcommands to: the
// first caller creates it, later callers get the same one, so registration order does not matter.
inline CLI::App& command_group(CLI::App& app, const std::string& name,
                               const std::string& description) {
  for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; }))
    if (sub->get_name() == name) return *sub;
  CLI::App* group = app.add_subcommand(name, description);
  group->require_subcommand(1);
  return *group;
}

// A database opened for reading; throws with the reader's message (it names the file).
inline db::Reader open_reader(const std::string& path) {
  db::Reader reader;
  db::Error err;
  if (reader.open(path, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  return reader;
}

// The CPU's model name, for benchmark reports (every figure names the machine it ran on).
inline std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown CPU";
}

// Options that pick a solver and its settings, shared by every command that simulates.
struct SolverOptions {
  std::string solver = "xpbd";
  std::string linear_solver = "ldlt";
  SolverSettings settings;
  void add_to(CLI::App& cmd) {
    cmd.add_option("--solver", solver, "mass-spring | pbd | xpbd | newton")->capture_default_str();
    cmd.add_option("--substeps", settings.substeps, "Sub-steps per frame")
        ->capture_default_str()
        ->check(number_in(1, kMaxSubsteps));
    cmd.add_option("--iterations", settings.iterations,
                   "Constraint iterations per sub-step (PBD, XPBD)")
        ->capture_default_str()
        ->check(number_in(1, kMaxIterations));
    cmd.add_option("--stretch-iterations", settings.stretch_iterations,
                   "XPBD stretch sweeps per sub-step (0: as --iterations)")
        ->capture_default_str()
        ->check(number_in(0, 1e6));
    cmd.add_option("--strain-limit", settings.strain_limit,
                   "XPBD Provot strain limit, e.g. 0.03 for 3 % (0: off)")
        ->capture_default_str()
        ->check(number_in(0, 1e6));
    cmd.add_option("--strain-limit-iterations", settings.strain_limit_iterations,
                   "XPBD strain-limit passes per sub-step")
        ->capture_default_str()
        ->check(number_in(1, kMaxIterations));
    cmd.add_option("--contact-rounds", settings.strain_limit_contact_rounds,
                   "XPBD: rounds of strain limit and frictionless collision after the collision "
                   "pass (0: off)")
        ->capture_default_str()
        ->check(number_in(0, kMaxIterations));
    cmd.add_option("--velocity-tolerance", settings.newton_velocity_tolerance,
                   "Newton: stop once no velocity changes by more than this, m/s (0: off)")
        ->capture_default_str()
        ->check(number_in(0, 1e6));
    cmd.add_option("--tolerance", settings.newton_tolerance,
                   "Newton force tolerance (relative to max m g)")
        ->capture_default_str();
    cmd.add_option("--linear-solver", linear_solver,
                   "Newton's linear solver: ldlt | cholmod | cholmod-supernodal | pcg | pcg-ic")
        ->capture_default_str();
    cmd.add_option("--threads", settings.threads, "OpenMP threads")
        ->capture_default_str()
        ->check(number_in(1, max_solver_threads()));
  }
  SolverKind kind() const { return parse_solver_kind(solver); }
  SolverSettings resolved() const {
    SolverSettings s = settings;
    s.linear_solver = parse_linear_solver_kind(linear_solver);
    return s;
  }
};

// Codec version 3's error contract as options in mm (db recode, precompute --codec v3): one
// wording and one check for every command that codes clips within it.
struct ContractOptions {
  double rms_mm = 0, max_mm = 0, jitter_mm = codec::kDefaultJitterCap * 1e3;
  void add_to(CLI::App& cmd) {
    cmd.add_option("--rms-mm", rms_mm, "--codec v3: cap on each frame's RMS vertex distance (mm)")
        ->check(number_in(0, 1e3, true));
    cmd.add_option("--max-mm", max_mm, "--codec v3: cap on any vertex's distance (mm)")
        ->check(number_in(0, 1e3, true));
    cmd.add_option("--jitter-mm", jitter_mm,
                   "--codec v3: cap on the second difference in time of any vertex's error (mm)")
        ->capture_default_str()
        ->check(number_in(0, 1e3, true));
  }
  // The contract in metres with --codec v3 (which needs --rms-mm and --max-mm); without it, none
  // (and the caps must not be given).
  codec::Contract resolved(bool v3) const {
    if (!v3) {
      if (rms_mm > 0 || max_mm > 0)
        throw CLI::ValidationError("--rms-mm/--max-mm", "only with --codec v3");
      return {};
    }
    if (!(rms_mm > 0) || !(max_mm > 0))
      throw CLI::ValidationError("--codec v3", "needs --rms-mm and --max-mm");
    return {1e-3 * rms_mm, 1e-3 * max_mm, 1e-3 * jitter_mm};
  }
};

// Where a command that writes several files into --out (`play`, `simulate`) writes them before
// everything is in place: a hidden directory inside --out, made before any work (so a bad --out
// is refused at once, not after the simulation), moved into place file by file once all are
// written, and removed on failure (with --out itself if this run created it), so a failed run
// changes nothing.
struct Staging {
  std::filesystem::path out, dir;
  bool created_out = false, done = false;
  // `command`: names the hidden directory, .COMMAND-partial-PID.
  Staging(const std::string& o, const std::string& command) : out(o) {
    std::error_code ec;
    if (std::filesystem::exists(out, ec) && !std::filesystem::is_directory(out, ec))
      throw std::runtime_error(o + ": exists and is not a directory");
    created_out = !std::filesystem::exists(out, ec);
    dir = out / ("." + command + "-partial-" + std::to_string(::getpid()));
    make_directories(dir.string());
  }
  Staging(const Staging&) = delete;
  Staging& operator=(const Staging&) = delete;
  std::string path(const std::string& name) const { return (dir / name).string(); }
  void commit(const std::vector<std::string>& names) {
    for (const std::string& name : names) {
      const std::filesystem::path target = out / name;
      std::error_code ec;
      if (std::filesystem::is_directory(dir / name)) std::filesystem::remove_all(target, ec);
      std::filesystem::rename(dir / name, target, ec);
      if (ec)
        throw std::runtime_error(target.string() + ": cannot move into place: " + ec.message());
    }
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    done = true;
  }
  ~Staging() {
    if (done) return;
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    if (created_out) std::filesystem::remove(out, ec);  // only if empty
  }
};

}  // namespace clothdb::cli
