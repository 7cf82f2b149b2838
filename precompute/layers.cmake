# The precompute's layers, lowest first: a folder may include headers of its own layer and of lower
# layers (and database/), never of a higher one. Read by precompute/CMakeLists.txt (one static
# library per layer, each linking the one below) and by check_layers.cmake (the include check that
# fails the build, and a test, when an arrow runs the wrong way).
set(PRECOMPUTE_LAYERS solvers character graph quality explore bench)
# 1. the cloth model, the four solvers, their candidate settings, the hard-case scenes, output,
#    and compress/ (codec v2's garment subspace and `db recode`: database and Eigen only)
set(PRECOMPUTE_LAYER_solvers cloth solvers hard_cases report compress)
# 2. skeletons and motion, garments, the character scene (simulation along poses), exchange
#    formats and the renderer
set(PRECOMPUTE_LAYER_character character garment character_scene exchange render)
# 3. the primary motion graph (Kovar et al. 2002)
set(PRECOMPUTE_LAYER_graph graph)
# 4. clip quality metrics
set(PRECOMPUTE_LAYER_quality quality)
# 5. the explorer (Kim et al. 2013), the precompute orchestration, MPI, and clip editing
set(PRECOMPUTE_LAYER_explore explore edit)
# 6. benchmarks
set(PRECOMPUTE_LAYER_bench bench)
