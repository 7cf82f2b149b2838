// The files a scene is built from, stored in the database at precompute so that it rebuilds the
// same scene from any directory (docs/DATABASE.md#stored-sources): the scene text (meta `scene`),
// the motion manifest and the garment's mesh file (table source_file). Motion files are not
// stored but found by their content hash (table motion_file), at their recorded path or in a
// folder given with --motions.
#pragma once

#include <string>
#include <vector>

#include "character_scene/character_scene.hpp"
#include "database/format/reader.hpp"

namespace clothdb {

// The motion file of each of the scene's clips, in its clip order (what motion_file records).
std::vector<std::string> scene_motion_files(const SceneFile& file);

// The manifest and garment mesh of `file` as source_file rows (paths as the files spell them).
std::vector<db::SourceFile> scene_sources(const SceneFile& file);

// The first field where two JSON texts differ, as "material.damping: stored 0.001, given 0.002"
// (empty when they are equal as JSON; "not JSON" when either is not).
std::string json_difference(const std::string& stored, const std::string& given);

// The scene `file` is the one the database holds (meta `scene`, its stored manifest and mesh),
// or a sentence naming the first difference: the file and field. Empty: the same, or nothing
// stored to compare with.
std::string scene_difference(db::Reader& reader, const SceneFile& file);

// A motion file the database records (path and content hash), found: at `resolved_now` (where the
// scene's manifest points from here; may be empty), at its recorded path, or in `motions_dir`
// (by name, then by content hash of every file under it). Throws naming the database, the file
// and every place tried.
std::string locate_motion_file(const db::MotionFile& file, const std::string& resolved_now,
                               const std::string& motions_dir, const std::string& database);

// Points every scene clip of `file.manifest` at its motion file as found by locate_motion_file
// (the database's motion_file rows are in scene-clip order; see write_primary_graph).
void relocate_motion_files(SceneFile& file, const std::vector<db::MotionFile>& rows,
                           const std::string& motions_dir, const std::string& database);

// True when the database stores its scene's sources (made by a precompute since schema 5).
bool has_stored_scene(db::Reader& reader);

// The scene built from what the database stores (meta `scene` + source_file), its motion files
// located as above; file.path and file.text are the stored ones. The stored files are written to
// a temporary folder for the scene loader and removed before it returns. Throws when the
// database stores no sources.
CharacterScene build_stored_scene(db::Reader& reader, const std::string& motions_dir);

}  // namespace clothdb
