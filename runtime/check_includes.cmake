# Fails if a source of the runtime library or of the database code it uses pulls in Eigen, assimp
# or OpenMP (the library a game links depends on SQLite and zstd only), or if the runtime library
# includes the store side of the database (database/store/: the writer, the edit log; clothrt
# links only clothdb_format). runtime/tools/ are writers' tools, not the library.
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
file(GLOB_RECURSE runtime_files "${RUNTIME_DIR}/*.c" "${RUNTIME_DIR}/*.h" "${RUNTIME_DIR}/*.cpp"
     "${RUNTIME_DIR}/*.hpp")
foreach(f IN LISTS runtime_files)
  if(f MATCHES "/runtime/tools/")
    continue()
  endif()
  file(STRINGS "${f}" lines REGEX "^[ \t]*#[ \t]*include[ \t]*\"database/store/")
  foreach(line IN LISTS lines)
    string(APPEND bad "\n  ${f}: ${line} (the runtime links clothdb_format only)")
  endforeach()
endforeach()
if(bad)
  message(FATAL_ERROR "the runtime must not use Eigen, assimp, OpenMP or the database's store side:${bad}")
endif()
