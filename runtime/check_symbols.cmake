# Fails if the runtime (clothrt and the database code it links, clothdb_format) references any
# symbol of SQLite's session extension: a game's own SQLite is usually built without it, and only
# the edit log (clothdb_store) needs it. As a check that the check can fail, the store library,
# which does use the extension, must show those symbols.
# Usage: cmake -DNM=... -DRUNTIME_LIBS="a.a;b.a" -DSTORE_LIB=c.a -P check_symbols.cmake
function(session_symbols lib out)
  execute_process(COMMAND "${NM}" -A "${lib}" OUTPUT_VARIABLE text RESULT_VARIABLE rc
                  ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${NM} ${lib} failed: ${err}")
  endif()
  string(REGEX MATCHALL "[^\n]*sqlite3(session|changeset)_[A-Za-z_]*" found "${text}")
  set(${out} "${found}" PARENT_SCOPE)
endfunction()

foreach(lib IN LISTS RUNTIME_LIBS)
  session_symbols("${lib}" found)
  if(found)
    string(REPLACE ";" "\n  " found "${found}")
    message(FATAL_ERROR "the runtime references SQLite's session extension:\n  ${found}")
  endif()
endforeach()
session_symbols("${STORE_LIB}" found)
if(NOT found)
  message(FATAL_ERROR "${STORE_LIB} shows no session extension symbol: the check cannot see them")
endif()
message(STATUS "no session extension symbol in ${RUNTIME_LIBS}")
