// `clothdb clip export|import|resim|flag|unflag|delete|log FILE ID ...` and `clothdb undo FILE`:
// fixing bad clips by hand or by re-simulating (docs/GUIDE.md#fixing-a-bad-clip;
// precompute/edit/clip_edit.hpp). Each command is one logged edit in one transaction; `undo`
// reverts the newest exactly.
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "cli_util.hpp"
#include "commands.hpp"
#include "edit/clip_edit.hpp"
#include "explore/auto_solver.hpp"

namespace clothdb::cli {

namespace {

std::string default_author() {
  if (const char* user = std::getenv("USER"); user && *user) return user;
  return "uid " + std::to_string(getuid());
}

struct Common {
  std::string file, scene, motions, author = default_author();
  int64_t id = 0;
  double epsilon_mm = 0;
};

void add_common(CLI::App* cmd, Common& c, bool with_id = true) {
  cmd->add_option("FILE", c.file, "clothdb database")->required();
  if (with_id) cmd->add_option("ID", c.id, "Cloth clip id (see `clothdb clips list`)")->required();
  cmd->add_option("--scene", c.scene,
                  "Scene file the database was made from (default: the scene, manifest and "
                  "garment mesh the database stores; needed only for files made before they were "
                  "stored; refused, naming the field, if it is not the stored one)");
  cmd->add_option("--motions", c.motions,
                  "Folder holding the motion files, if they are not at their recorded paths "
                  "(found by content hash)");
  cmd->add_option("--epsilon", c.epsilon_mm,
                  "Error bound in mm for the continuity checks (default: the precompute's)");
  cmd->add_option("--author", c.author, "Name in the edit log")->capture_default_str();
}

EditContext open(const Common& c) {
  return open_edit(c.file, c.scene, 1e-3 * c.epsilon_mm, c.author, c.motions);
}

void print_edges(const std::vector<EdgeCheck>& edges, double epsilon) {
  char over[48];
  std::snprintf(over, sizeof over, " > epsilon %.2f mm", 1e3 * epsilon);
  for (const EdgeCheck& e : edges)
    std::printf(
        "  edge %lld (clip %lld -> state %lld)%s: blend error %.2f -> at most %.2f mm, "
        "pop %.2f mm%s\n",
        (long long)e.edge, (long long)e.from_clip, (long long)e.to_state,
        e.into_start ? " into the clip's start" : " out of the clip", 1e3 * e.blend_before,
        1e3 * e.blend_after, 1e3 * e.pop, e.broken ? over : "");
}

void print_metrics(const db::ClipMetrics& m) {
  std::printf(
      "  metrics: max strain %.2f %%, max penetration %.2f mm, mean penetration %.2f mm, "
      "jitter %.3f mm\n",
      100 * m.max_strain, 1e3 * m.max_penetration,
      std::isnan(m.mean_penetration) ? 0.0 : 1e3 * m.mean_penetration,
      std::isnan(m.jitter) ? 0.0 : 1e3 * m.jitter);
}

}  // namespace

void register_edit_commands(CLI::App& app) {
  CLI::App& clip = command_group(app, "clip", "Inspect and edit single cloth clips");

  // export
  struct ExportArgs {
    Common c;
    std::string out;
    bool no_body = false;
  };
  auto ea = std::make_shared<ExportArgs>();
  CLI::App* exp = clip.add_subcommand(
      "export",
      "Write a clip for Blender: DIR/cloth.obj + DIR/cloth.pc2 on the artist's mesh (its vertex "
      "order, faces, UVs and normals; import the OBJ keeping vertex order, add a Mesh Cache "
      "modifier with the PC2) and the body capsules as DIR/body.obj + "
      "DIR/body.pc2, in the clip's character space; edit, then `clip import FILE ID DIR`");
  add_common(exp, ea->c);
  exp->add_option("--out", ea->out, "Folder to write (created)")->required();
  exp->add_flag("--no-body", ea->no_body,
                "Export the cloth alone (without it, an export whose scene cannot be rebuilt "
                "fails and writes nothing)");
  exp->callback([ea] {
    db::Reader reader = open_reader(ea->c.file);
    const ExportedClip files =
        export_clip(reader, ea->c.id, ea->out, ea->c.scene, ea->c.motions, !ea->no_body);
    std::printf("clip %lld -> %s, %s%s%s%s, %s\n", (long long)ea->c.id, files.cloth_obj.c_str(),
                files.cloth_pc2.c_str(), files.body_obj.empty() ? "" : ", ", files.body_obj.c_str(),
                files.body_pc2.empty() ? "" : (", " + files.body_pc2).c_str(),
                files.info_json.c_str());
    std::printf(
        "%d frames at %g fps: in Blender, Mesh Cache frame start 0, frame scale 1, scene frames "
        "0-%d at %g fps (docs/guide/blender.md)\n",
        files.frames, files.frame_rate, files.frames - 1, files.frame_rate);
  });

  // import
  struct ImportArgs {
    Common c;
    std::string path, on_break = "refuse";
    int ramp_frames = 8;
  };
  auto ia = std::make_shared<ImportArgs>();
  CLI::App* imp = clip.add_subcommand(
      "import",
      "Read an edited clip back (a PC2, or the folder `clip export` wrote; in the artist's vertex "
      "order or the simulation's): checks vertex and frame counts, re-encodes within the codec "
      "bound, re-measures its quality and checks "
      "continuity at both ends; an end whose edges' blend error would exceed epsilon is refused, "
      "re-blended or ramped (--on-break). Frames that are no edit (frozen, shifted, retimed, "
      "rotated or in world space) are refused naming the cause; frames equal to the stored clip "
      "within the codec bound write and log nothing and exit with status 3 (no change)");
  add_common(imp, ia->c);
  imp->add_option("PATH", ia->path, "cloth.pc2, or the folder holding it")->required();
  imp->add_option("--on-break", ia->on_break,
                  "refuse (write nothing) | reblend (record the larger blend errors: the runtime "
                  "blends across the jump) | ramp (fade the edit out toward the original frames "
                  "at a broken end)")
      ->capture_default_str();
  imp->add_option("--ramp-frames", ia->ramp_frames, "--on-break ramp: frames to fade over")
      ->capture_default_str()
      ->check(number_in(0, 1000));
  imp->callback([ia] {
    const OnBreak on_break = parse_on_break(ia->on_break);
    EditContext ctx = open(ia->c);
    db::ClothClip row;
    read_clip_frames(ctx.reader, ia->c.id, &row);
    db::ArtistMesh artist;
    db::Error mesh_err;
    if (ctx.reader.artist_mesh(&artist, &mesh_err) != db::Status::Ok)
      throw std::runtime_error(mesh_err.message);
    EditedCache cache = read_edited_cache(
        ia->path, artist, static_cast<uint32_t>(ctx.scene.scene.model.vertex_count()),
        row.frame_count, ctx.scene.graph.rate);
    ImportOptions o;
    o.on_break = on_break;
    o.ramp_frames = ia->ramp_frames;
    o.header_start_frame = cache.start_frame;
    ImportReport r;
    try {
      r = import_clip(ctx, ia->c.id, std::move(cache.frames), o);
    } catch (const NoChange& e) {
      std::fprintf(stderr, "clothdb: %s: clip %lld: %s\n", ia->c.file.c_str(), (long long)ia->c.id,
                   e.what());
      throw CLI::RuntimeError(kNoChangeExitStatus);
    }
    std::printf(
        "clip %lld: the edit moves its start by %.2f mm and its end by %.2f mm (epsilon "
        "%.2f mm)%s%s\n",
        (long long)ia->c.id, 1e3 * r.start_move, 1e3 * r.end_move, 1e3 * ctx.epsilon,
        r.ramped_start ? "; start ramped back" : "", r.ramped_end ? "; end ramped back" : "");
    print_edges(r.edges, ctx.epsilon);
    if (r.edit == 0)
      throw std::runtime_error(ia->c.file + ": clip " + std::to_string(ia->c.id) +
                               ": the edit breaks continuity at the edges marked above; nothing "
                               "was written (--on-break reblend or ramp to accept it)");
    std::printf("  before (the stored clip, decoded):\n  ");
    print_metrics(r.metrics_before);
    std::printf("  after (the edit, re-encoded):\n  ");
    print_metrics(r.metrics);
    if (!r.strain_warning.empty()) std::printf("warning: %s\n", r.strain_warning.c_str());
    if (o.header_start_frame != 0)
      std::printf(
          "note: the PC2 header's start frame is %g, `clip export` writes 0; its frames match the "
          "clip's frame by frame (checked by content), so they were taken as frames 0-%d\n",
          o.header_start_frame, row.frame_count - 1);
    std::printf("imported as edit %lld (codec error %.3f mm); `clothdb undo %s` reverts it\n",
                (long long)r.edit, 1e3 * r.codec_error, ia->c.file.c_str());
  });

  // resim
  struct ResimArgs {
    Common c;
    SolverOptions solver;
    long max_frames = 2000;
    int batch = 8;
    bool quiet = false;
  };
  auto ra = std::make_shared<ResimArgs>();
  CLI::App* res = clip.add_subcommand(
      "resim",
      "Re-simulate a clip from its start state with other solver settings (default: the "
      "database's). If its new end is within epsilon of a state at its node it links there; "
      "otherwise the end is a new state and the clips from it are simulated too, onward until "
      "every new end links back within epsilon (the explorer's rule) or --max-frames runs out");
  add_common(res, ra->c);
  ra->solver.add_to(*res);
  res->add_option("--max-frames", ra->max_frames,
                  "Budget for carrying the change forward, frames simulated (0: until every new "
                  "end links back, which on a database that has not converged may not happen)")
      ->capture_default_str()
      ->check(number_in(0, 1e12));
  res->add_option("--batch", ra->batch, "Carried-forward dead ends per batch")
      ->capture_default_str()
      ->check(positive_number());
  res->add_flag("--quiet", ra->quiet, "No progress bar");
  res->callback([ra, res] {
    EditContext ctx = open(ra->c);
    db::ClothClip row;
    read_clip_frames(ctx.reader, ra->c.id, &row);  // a clear error for a wrong id, before anything
    ResimOptions o;
    // The database's setting, with what was given on the command line over it.
    o.solver = ctx.scene.scene.file.solver;
    o.settings = ctx.scene.scene.file.settings;
    const SolverSettings given = ra->solver.resolved();
    if (res->count("--solver")) o.solver = ra->solver.kind();
    if (res->count("--substeps")) o.settings.substeps = given.substeps;
    if (res->count("--iterations")) o.settings.iterations = given.iterations;
    if (res->count("--tolerance")) o.settings.newton_tolerance = given.newton_tolerance;
    if (res->count("--linear-solver")) o.settings.linear_solver = given.linear_solver;
    o.threads = ra->solver.settings.threads;
    o.max_frames = ra->max_frames;
    o.batch = ra->batch;
    o.progress = !ra->quiet;
    std::fprintf(stderr, "clip resim: clip %lld with %s %s...\n", (long long)ra->c.id,
                 solver_name(o.solver), solver_settings_json(o.solver, o.settings).c_str());
    const ResimReport r = resim_clip(ctx, ra->c.id, o);
    print_metrics(r.metrics);
    std::printf("clip %lld re-simulated: its new end is %.2f mm from the state its edge led to; ",
                (long long)ra->c.id, 1e3 * r.end_move);
    if (!r.new_state)
      std::printf(
          "linked to state %lld (blend error %.2f mm, epsilon %.2f mm): not carried "
          "forward\n",
          (long long)r.linked_to, 1e3 * r.blend_error, 1e3 * ctx.epsilon);
    else
      std::printf(
          "no state within epsilon %.2f mm, so it is new state %lld; carried forward "
          "through %d generations: %d new states, %d new clips, %ld frames, %d dead ends "
          "left%s\n",
          1e3 * ctx.epsilon, (long long)r.linked_to, r.depth, r.states_added, r.clips_added,
          r.frames_added, r.dead_ends_left,
          r.dead_ends_left ? " (the budget ran out; the runtime falls back there)" : "");
    std::printf("edit %lld; `clothdb undo %s` reverts it\n", (long long)r.edit, ra->c.file.c_str());
  });

  // flag / unflag
  for (const bool flag : {true, false}) {
    auto fa = std::make_shared<Common>();
    CLI::App* cmd =
        clip.add_subcommand(flag ? "flag" : "unflag",
                            flag ? "Mark a clip as looking wrong (status flagged; logged, undoable)"
                                 : "Clear a clip's flag (logged, undoable)");
    add_common(cmd, *fa);
    cmd->callback([fa, flag] {
      EditContext ctx = open(*fa);
      const int64_t edit = set_clip_flag(ctx, fa->id, flag);
      std::printf("clip %lld %s (edit %lld)\n", (long long)fa->id, flag ? "flagged" : "unflagged",
                  (long long)edit);
    });
  }

  // delete
  auto da = std::make_shared<Common>();
  CLI::App* del = clip.add_subcommand(
      "delete",
      "Delete a clip. Its start state then lacks cloth along its edge, so the edges into that "
      "state are re-routed to the nearest other state at its node with cloth along every way "
      "out (refused when there is none)");
  add_common(del, *da);
  del->callback([da] {
    EditContext ctx = open(*da);
    const size_t gaps_before = coverage_gaps(ctx.reader, ctx.scene.graph).size();
    const DeleteReport r = delete_clip(ctx, da->id);
    std::printf("clip %lld deleted (edit %lld); %zu edges into its start state %lld re-routed%s\n",
                (long long)da->id, (long long)r.edit, r.rerouted.size(), (long long)r.start_state,
                r.replacement ? (" to state " + std::to_string(r.replacement)).c_str() : "");
    print_edges(r.rerouted, ctx.epsilon);
    const size_t gaps_after = coverage_gaps(ctx.reader, ctx.scene.graph).size();
    std::printf("states reachable without cloth along some edge: %zu before, %zu after\n",
                gaps_before, gaps_after);
  });

  // log
  auto la = std::make_shared<std::string>();
  CLI::App* log = clip.add_subcommand("log", "The edit log, oldest first");
  log->add_option("FILE", *la, "clothdb database")->required();
  log->callback([la] {
    db::Reader reader = open_reader(*la);
    db::Error err;
    std::vector<db::EditLogEntry> entries;
    if (reader.edit_log(&entries, &err) != db::Status::Ok) throw std::runtime_error(err.message);
    std::printf("%zu edits in %s\n", entries.size(), la->c_str());
    for (const auto& e : entries)
      std::printf("%5lld  %s  %-10s clip %-6lld %s: %s\n", (long long)e.id, e.time.c_str(),
                  e.action.c_str(), (long long)e.clip, e.author.c_str(), e.description.c_str());
  });

  // undo
  struct UndoArgs {
    std::string file, author = default_author();
  };
  auto ua = std::make_shared<UndoArgs>();
  CLI::App* undo = app.add_subcommand(
      "undo",
      "Revert the newest edit of a database (clip import, resim, flag, unflag, delete) exactly: "
      "every row it changed, added or removed is as before; the undo is logged too");
  undo->add_option("FILE", ua->file, "clothdb database")->required();
  undo->add_option("--author", ua->author, "Name in the edit log")->capture_default_str();
  undo->callback([ua] {
    db::Writer writer = db::Writer::open(ua->file);
    const db::EditLogEntry e = writer.undo_last(ua->author);
    std::printf("undid edit %lld (%s of clip %lld: %s)\n", (long long)e.id, e.action.c_str(),
                (long long)e.clip, e.description.c_str());
  });
}

}  // namespace clothdb::cli
