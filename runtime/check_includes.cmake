# Fails if a source of the runtime library or of the database code it uses pulls in Eigen, assimp
# or OpenMP: the library a game links depends on SQLite and zstd only.
# Usage: cmake -DRUNTIME_DIR=... -DDATABASE_DIR=... -P check_includes.cmake
set(bad "")
foreach(dir IN ITEMS "${RUNTIME_DIR}" "${DATABASE_DIR}")
  file(GLOB_RECURSE files "${dir}/*.c" "${dir}/*.h" "${dir}/*.cpp" "${dir}/*.hpp")
  foreach(f IN LISTS files)
    file(STRINGS "${f}" lines REGEX "^[ \t]*#[ \t]*(include[ \t]*[<\"](Eigen|unsupported/Eigen|assimp|omp\\.h)|pragma[ \t]+omp)")
    foreach(line IN LISTS lines)
      string(APPEND bad "\n  ${f}: ${line}")
    endforeach()
  endforeach()
endforeach()
if(bad)
  message(FATAL_ERROR "the runtime must not use Eigen, assimp or OpenMP:${bad}")
endif()
