#include "database/store/run_settings.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

namespace clothdb {

using json = nlohmann::json;

namespace {

// Limits: far beyond any useful setting, near enough that a typo (2^40 sub-steps, 1e5 threads)
// is refused before it allocates or spawns anything.
constexpr int kMaxThreads = 1024;
constexpr int kMaxHalvings = 30;

std::string shown(double d) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%g", d);
  return buf;
}

[[noreturn]] void refuse(const std::string& where, const std::string& field,
                         const std::string& problem) {
  throw SettingsError(where + ": " + field + ": " + problem);
}

// The field table. Every serialiser, parser and validator below is one visitor over it, so a
// field added here is written, read and checked everywhere a setting travels.
template <class V>
void visit_solver_fields(SolverSettings& s, V& v) {
  v.integer("substeps", s.substeps, 1, kMaxSubsteps);
  v.integer("iterations", s.iterations, 1, kMaxIterations);
  v.number("pbd_stretch_stiffness", s.pbd_stretch_stiffness, 0.0, 1.0);
  // Negative: derived from the material (pbd.cpp).
  v.number("pbd_bend_stiffness", s.pbd_bend_stiffness, -1.0, 1.0);
  v.number("provot_critical_rate", s.provot_critical_rate, 1e-6, 10.0);
  v.number("tolerance", s.newton_tolerance, 1e-16, 1.0);
  v.number("newton_velocity_tolerance", s.newton_velocity_tolerance, 0.0, 100.0);
  v.boolean("newton_accept_decrease", s.newton_accept_decrease);
  v.integer("newton_max_iterations", s.newton_max_iterations, 1, kMaxIterations);
  v.integer("newton_max_halvings", s.newton_max_halvings, 0, kMaxHalvings);
  v.choice("newton_guess", s.newton_guess,
           {{"start", SolverSettings::Guess::Start},
            {"inertial", SolverSettings::Guess::Inertial},
            {"extrapolate", SolverSettings::Guess::Extrapolate}});
  v.number("newton_reuse_contraction", s.newton_reuse_contraction, 0.0, 0.999);
  v.boolean("newton_exact_hessian", s.newton_exact_hessian);
  v.boolean("newton_projected_first", s.newton_projected_first);
  v.choice("linear_solver", s.linear_solver,
           {{"ldlt", LinearSolverKind::SimplicialLDLT},
            {"cholmod", LinearSolverKind::Cholmod},
            {"pcg", LinearSolverKind::ConjugateGradient},
            {"pcg-ic", LinearSolverKind::ConjugateGradientIC},
            {"cholmod-supernodal", LinearSolverKind::CholmodSupernodal}});
  v.integer("threads", s.threads, 1, kMaxThreads);
  v.boolean("tethers", s.tethers);
  v.integer("stretch_iterations", s.stretch_iterations, 0, kMaxIterations);
  v.number("strain_limit", s.strain_limit, 0.0, 10.0);
  v.integer("strain_limit_iterations", s.strain_limit_iterations, 1, kMaxIterations);
  // Below 2: projected over-relaxation converges for 0 < omega < 2 (Cryer 1971).
  v.optional_number("strain_limit_relaxation", s.strain_limit_relaxation, 1.0, 1.99, 1.0);
  v.integer("strain_limit_contact_rounds", s.strain_limit_contact_rounds, 0, kMaxIterations);
  // Below 1: at rho = 1 the weights grow without bound (omega -> 2).
  v.optional_number("chebyshev_rho", s.chebyshev_rho, 0.0, 0.999, 0.0);
  // Up to 50 mm: thicker than any garment layer; 0 (off) is not written.
  v.grouped("self_collision", "thickness_mm", s.self_collision_thickness_mm, 0.0, 50.0);
  // 0 (off) is not written; a procedural garment needs at least 16 vertices (garment.cpp).
  v.optional_integer("coarse_vertices", s.coarse_vertices, 16, 100000000, 0);
}

template <class V>
void visit_codec_fields(db::CodecSettings& c, V& v) {
  v.number("position_bound", c.position_bound, 1e-9, 1.0);
  v.number("velocity_bound", c.velocity_bound, 1e-9, 100.0);
  int key = static_cast<int>(c.key_interval);
  v.integer("key_interval", key, 0, 1 << 20);
  c.key_interval = static_cast<uint32_t>(key);
  v.integer("zstd_level", c.zstd_level, 1, 22);
}

template <class V>
void visit_run_fields(db::RunSettings& r, V& v) {
  // Up to 1 m: a bound larger than the garment means nothing.
  v.number("epsilon_m", r.epsilon, 1e-9, 1.0);
  v.number("cpu_hours", r.cpu_hours, 0.0, 1e6);
  long frames = r.max_frames;
  v.integer64("max_frames", frames, 0, 1L << 40);
  r.max_frames = frames;
  v.integer("threads", r.threads, 1, kMaxThreads);
  v.integer("batch", r.batch, 1, 1 << 16);
  v.boolean("auto_solver", r.auto_solver);
  long clip = r.resim_clip;
  v.integer64("resim_clip", clip, 0, std::numeric_limits<long>::max());
  r.resim_clip = clip;
  int modes = static_cast<int>(r.subspace_modes);
  v.integer("subspace_modes", modes, 0, static_cast<int>(codec::kMaxBasisModes));
  r.subspace_modes = static_cast<uint32_t>(modes);
  v.boolean("subspace_body_frame", r.subspace_body_frame);
}

void check_range(const std::string& where, const std::string& field, double d, double lo,
                 double hi) {
  if (!std::isfinite(d) || d < lo || d > hi)
    refuse(
        where, field,
        "must be a finite number in [" + shown(lo) + ", " + shown(hi) + "] (got " + shown(d) + ")");
}

void check_range(const std::string& where, const std::string& field, long long i, long long lo,
                 long long hi) {
  if (i < lo || i > hi)
    refuse(where, field,
           "must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "] (got " +
               std::to_string(i) + ")");
}

struct Validator {
  std::string where, prefix;
  void number(const char* name, double& d, double lo, double hi) {
    check_range(where, prefix + name, d, lo, hi);
  }
  void integer(const char* name, int& i, int lo, int hi) {
    check_range(where, prefix + name, static_cast<long long>(i), lo, hi);
  }
  void integer64(const char* name, long& i, long lo, long hi) {
    check_range(where, prefix + name, static_cast<long long>(i), lo, hi);
  }
  void boolean(const char*, bool&) {}
  void optional_number(const char* name, double& d, double lo, double hi, double) {
    number(name, d, lo, hi);
  }
  void optional_integer(const char* name, int& i, int lo, int hi, int off) {
    if (i != off) integer(name, i, lo, hi);
  }
  void grouped(const char* group, const char* name, double& d, double lo, double hi) {
    check_range(where, prefix + group + "." + name, d, lo, hi);
  }
  template <class E>
  void choice(const char* name, E& e, std::initializer_list<std::pair<const char*, E>> options) {
    for (const auto& o : options)
      if (o.second == e) return;
    refuse(where, prefix + name, "unknown value " + std::to_string(static_cast<int>(e)));
  }
};

struct ToJson {
  json out = json::object();
  bool include_threads = true;
  void number(const char* name, double& d, double, double) { out[name] = d; }
  void integer(const char* name, int& i, int, int) {
    if (include_threads || std::string(name) != "threads") out[name] = i;
  }
  void integer64(const char* name, long& i, long, long) { out[name] = i; }
  void boolean(const char* name, bool& b) { out[name] = b; }
  // A field at its `off` value is left out, so records made before it existed (and settings
  // that leave it off) are written byte-identically.
  void optional_number(const char* name, double& d, double, double, double off) {
    if (d != off) out[name] = d;
  }
  void optional_integer(const char* name, int& i, int, int, int off) {
    if (i != off) out[name] = i;
  }
  // A group whose only field is 0 means off and is left out.
  void grouped(const char* group, const char* name, double& d, double, double) {
    if (d != 0.0) out[group] = {{name, d}};
  }
  template <class E>
  void choice(const char* name, E& e, std::initializer_list<std::pair<const char*, E>> options) {
    for (const auto& o : options)
      if (o.second == e) out[name] = o.first;
  }
};

struct FromJson {
  const json& in;
  std::string where, prefix;
  std::set<std::string> seen;
  const json* get(const char* name) {
    seen.insert(name);
    auto it = in.find(name);
    return it == in.end() ? nullptr : &*it;
  }
  void number(const char* name, double& d, double lo, double hi) {
    const json* v = get(name);
    if (!v) return;
    if (!v->is_number()) refuse(where, prefix + name, "expected a number, got " + v->dump());
    d = v->get<double>();
    check_range(where, prefix + name, d, lo, hi);
  }
  void optional_number(const char* name, double& d, double lo, double hi, double) {
    number(name, d, lo, hi);
  }
  long long whole(const char* name, const json* v, long long lo, long long hi) {
    // Integers only, checked before narrowing: 2^40 sub-steps must not wrap to a small number.
    if (v->is_number_unsigned()) {
      const auto u = v->get<unsigned long long>();
      if (u > static_cast<unsigned long long>(hi))
        refuse(where, prefix + name,
               "must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                   "] (got " + v->dump() + ")");
      return static_cast<long long>(u);
    }
    if (!v->is_number_integer())
      refuse(where, prefix + name, "expected an integer, got " + v->dump());
    const long long i = v->get<long long>();
    check_range(where, prefix + name, i, lo, hi);
    return i;
  }
  void integer(const char* name, int& i, int lo, int hi) {
    if (const json* v = get(name)) i = static_cast<int>(whole(name, v, lo, hi));
  }
  // The off value is accepted as written (e.g. "coarse_vertices": 0).
  void optional_integer(const char* name, int& i, int lo, int hi, int off) {
    if (const json* v = get(name)) {
      const long long k = whole(name, v, std::min<long long>(lo, off), hi);
      if (k != off && k < lo) check_range(where, prefix + name, k, lo, hi);
      i = static_cast<int>(k);
    }
  }
  void integer64(const char* name, long& i, long lo, long hi) {
    if (const json* v = get(name)) i = static_cast<long>(whole(name, v, lo, hi));
  }
  void boolean(const char* name, bool& b) {
    const json* v = get(name);
    if (!v) return;
    if (!v->is_boolean()) refuse(where, prefix + name, "expected true or false, got " + v->dump());
    b = v->get<bool>();
  }
  void grouped(const char* group, const char* name, double& d, double lo, double hi) {
    const json* g = get(group);
    if (!g) return;
    if (!g->is_object())
      refuse(where, prefix + group,
             "expected an object such as {\"" + std::string(name) + "\": 4}");
    FromJson inner{*g, where, prefix + group + ".", {}};
    inner.number(name, d, lo, hi);
    inner.only();
  }
  template <class E>
  void choice(const char* name, E& e, std::initializer_list<std::pair<const char*, E>> options) {
    const json* v = get(name);
    if (!v) return;
    std::string names;
    for (const auto& o : options) {
      if (v->is_string() && v->get<std::string>() == o.first) {
        e = o.second;
        return;
      }
      names += std::string(names.empty() ? "" : ", ") + o.first;
    }
    refuse(where, prefix + name, "expected one of " + names + ", got " + v->dump());
  }
  // Fields the table does not know are refused: a misspelt option must not be silently ignored.
  // The message names the nearest known field when it is a likely misspelling, else every one.
  void only(std::initializer_list<const char*> also = {}) {
    for (const char* a : also) seen.insert(a);
    for (auto it = in.begin(); it != in.end(); ++it) {
      if (seen.count(it.key())) continue;
      std::string nearest, known;
      size_t best = std::numeric_limits<size_t>::max();
      for (const std::string& k : seen) {
        known += (known.empty() ? "" : ", ") + k;
        const size_t d = edit_distance(it.key(), k);
        if (d < best) best = d, nearest = k;
      }
      refuse(where, prefix + it.key(),
             best <= 2 ? "unknown field; did you mean '" + nearest + "'?"
                       : "unknown field (known: " + known + ")");
    }
  }
  // Levenshtein distance: insertions, deletions and substitutions.
  static size_t edit_distance(const std::string& a, const std::string& b) {
    std::vector<size_t> row(b.size() + 1);
    for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
    for (size_t i = 1; i <= a.size(); ++i) {
      size_t diagonal = row[0];
      row[0] = i;
      for (size_t j = 1; j <= b.size(); ++j) {
        const size_t above = row[j];
        row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] != b[j - 1])});
        diagonal = above;
      }
    }
    return row[b.size()];
  }
};

json parse_object(const std::string& text, const std::string& where) {
  const json j = json::parse(text, nullptr, false);
  if (j.is_discarded()) throw SettingsError(where + ": not valid JSON");
  if (!j.is_object()) throw SettingsError(where + ": expected a JSON object");
  return j;
}

json solver_object(SolverKind kind, SolverSettings s, bool include_threads) {
  ToJson w;
  w.include_threads = include_threads;
  visit_solver_fields(s, w);
  w.out["name"] = solver_name(kind);
  return w.out;
}

void solver_from_object(const json& j, const std::string& where, const std::string& prefix,
                        SolverKind* kind, SolverSettings* s) {
  FromJson r{j, where, prefix, {}};
  if (const json* name = r.get("name")) {
    if (!name->is_string()) refuse(where, prefix + "name", "expected a string");
    try {
      *kind = parse_solver_kind(name->get<std::string>());
    } catch (const std::invalid_argument& e) {
      refuse(where, prefix + "name", e.what());
    }
  }
  visit_solver_fields(*s, r);
  r.only();
}

}  // namespace

const char* solver_name(SolverKind kind) {
  switch (kind) {
    case SolverKind::MassSpring:
      return "mass-spring";
    case SolverKind::Pbd:
      return "pbd";
    case SolverKind::Xpbd:
      return "xpbd";
    case SolverKind::Newton:
      return "newton";
  }
  return "unknown";
}

SolverKind parse_solver_kind(const std::string& name) {
  for (SolverKind k :
       {SolverKind::MassSpring, SolverKind::Pbd, SolverKind::Xpbd, SolverKind::Newton})
    if (name == solver_name(k)) return k;
  throw std::invalid_argument("unknown solver '" + name +
                              "' (expected mass-spring, pbd, xpbd or newton)");
}

const char* linear_solver_name(LinearSolverKind kind) {
  switch (kind) {
    case LinearSolverKind::SimplicialLDLT:
      return "ldlt";
    case LinearSolverKind::Cholmod:
      return "cholmod";
    case LinearSolverKind::ConjugateGradient:
      return "pcg";
    case LinearSolverKind::ConjugateGradientIC:
      return "pcg-ic";
    case LinearSolverKind::CholmodSupernodal:
      return "cholmod-supernodal";
  }
  return "unknown";
}

LinearSolverKind parse_linear_solver_kind(const std::string& name) {
  for (LinearSolverKind k :
       {LinearSolverKind::SimplicialLDLT, LinearSolverKind::Cholmod,
        LinearSolverKind::ConjugateGradient, LinearSolverKind::ConjugateGradientIC,
        LinearSolverKind::CholmodSupernodal})
    if (name == linear_solver_name(k)) return k;
  throw std::invalid_argument("unknown linear solver '" + name +
                              "' (expected ldlt, cholmod, cholmod-supernodal, pcg or pcg-ic)");
}

std::string solver_settings_json(SolverKind kind, const SolverSettings& settings,
                                 bool include_threads) {
  validate_solver_settings(settings, "solver settings");
  return solver_object(kind, settings, include_threads).dump();
}

void parse_solver_settings_json(const std::string& text, const std::string& where, SolverKind* kind,
                                SolverSettings* settings, const std::string& field_prefix) {
  solver_from_object(parse_object(text, where), where, field_prefix, kind, settings);
}

void validate_solver_settings(const SolverSettings& settings, const std::string& where) {
  SolverSettings copy = settings;
  Validator v{where, ""};
  visit_solver_fields(copy, v);
}

namespace db {

void validate_run_settings(const RunSettings& run, const std::string& where) {
  RunSettings copy = run;
  Validator v{where, ""};
  visit_run_fields(copy, v);
  v.prefix = "solver.";
  visit_solver_fields(copy.settings, v);
  v.prefix = "codec.";
  visit_codec_fields(copy.codec, v);
}

std::string run_settings_json(const RunSettings& run) {
  validate_run_settings(run, "run settings");
  RunSettings copy = run;
  ToJson w;
  visit_run_fields(copy, w);
  w.out["solver"] = solver_object(run.solver, run.settings, true);
  ToJson c;
  visit_codec_fields(copy.codec, c);
  w.out["codec"] = c.out;
  return w.out.dump();
}

RunSettings parse_run_settings_json(const std::string& text, const std::string& where,
                                    const RunSettings& defaults) {
  const json j = parse_object(text, where);
  RunSettings run = defaults;
  FromJson r{j, where, "", {}};
  visit_run_fields(run, r);
  const auto solver = j.find("solver");
  if (solver != j.end() && solver->is_object()) {
    solver_from_object(*solver, where, "solver.", &run.solver, &run.settings);
  } else if (solver != j.end() && solver->is_string()) {
    // Schema-3 runs written before this record: "solver": "xpbd", "solver_settings": {...}.
    try {
      run.solver = parse_solver_kind(solver->get<std::string>());
    } catch (const std::invalid_argument& e) {
      refuse(where, "solver", e.what());
    }
    const auto legacy = j.find("solver_settings");
    if (legacy != j.end() && legacy->is_object())
      solver_from_object(*legacy, where, "solver_settings.", &run.solver, &run.settings);
  } else if (solver != j.end()) {
    refuse(where, "solver", "expected an object");
  }
  const auto codec = j.find("codec");
  if (codec != j.end()) {
    if (!codec->is_object()) refuse(where, "codec", "expected an object");
    FromJson c{*codec, where, "codec.", {}};
    visit_codec_fields(run.codec, c);
    c.only();
  }
  // Older rows also carried these as free-form members.
  r.only({"solver", "codec", "solver_settings", "carried_forward_from_clip"});
  if (const auto it = j.find("carried_forward_from_clip"); it != j.end() && it->is_number_integer())
    run.resim_clip = it->get<long>();
  validate_run_settings(run, where);
  return run;
}

}  // namespace db
}  // namespace clothdb
