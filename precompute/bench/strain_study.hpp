// `clothdb bench solvers --strain-study` (docs/guide/resolution.md): what a solver setting costs
// for the strain it holds. Per setting, one continuous run of the scene from its start, one
// thread: CPU milliseconds per frame, the p99 and the largest edge strain over every edge at every
// frame, and the distance to a converged run of the same model (the same setting at 8x the
// sub-steps: scene_reference, solvers/solver_candidates.hpp). Per strain target, the cheapest
// setting whose largest strain meets it is marked.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "hard_cases/hard_cases.hpp"
#include "solvers/solver_candidates.hpp"

namespace clothdb {

struct StrainStudyOptions {
  std::vector<SolverCandidate> settings;  // run in this order (threads forced to 1)
  int frames = 30;                        // output frames of every run (1/30 s each)
  std::vector<double> targets{0.01};      // largest-strain targets, (l - l0) / l0
  bool references = true;                 // also run each setting's converged reference
};

struct StrainStudyRow {
  std::string settings;  // the solver's describe(), plus " tethers=off" when they are off
  bool stable = true;
  std::string message;
  int frames = 0;  // frames run
  double cpu_ms_per_frame = NAN;
  // Over every edge at the end of every frame 1..frames (report::percentile's p99).
  double p99_strain = NAN, max_strain = NAN;
  double last_strain = NAN;  // the largest at the last frame
  // Against the same setting at 8x the sub-steps: RMS and largest vertex distance over frames
  // 1..frames (mm), and the reference's own cost. NaN when not run or unstable.
  std::string reference;
  double reference_rms_mm = NAN, reference_max_mm = NAN, reference_cpu_ms_per_frame = NAN;
  // The targets (of StrainStudy::targets) for which this is the cheapest setting that meets it.
  std::vector<double> cheapest_for;
};

struct StrainStudy {
  std::string scene, description;
  int vertices = 0, frames = 0;
  std::vector<double> targets;
  std::vector<StrainStudyRow> rows;
};

// A setting meets a target when its largest strain is at most the target, to the 0.001 % the
// tables print (a strain limit holds its edges at the limit, up to rounding).
bool meets_strain_target(double max_strain, double target);

StrainStudy run_strain_study(const ClothScene& scene, const StrainStudyOptions& options,
                             const std::function<void(const std::string&)>& progress);

std::string strain_study_markdown(const StrainStudy& study);
std::string strain_study_json(const std::vector<StrainStudy>& studies);

}  // namespace clothdb
