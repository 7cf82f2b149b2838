# The layer check must fail on a tree where a lower layer includes a higher one, naming the file
# and both layers, and pass on one where it does not.
# Usage: cmake -DCHECK=<check_layers.cmake> -DFIXTURE=<tests/layers/violation> -P expect_violation.cmake
execute_process(COMMAND ${CMAKE_COMMAND} -DPRECOMPUTE_DIR=${FIXTURE} -P ${CHECK}
                RESULT_VARIABLE rc ERROR_VARIABLE err OUTPUT_QUIET)
if(rc EQUAL 0)
  message(FATAL_ERROR "the layer check passed a tree where cloth/ includes explore/")
endif()
if(NOT err MATCHES "cloth/bad.hpp \\(layer solvers\\) includes explore/ \\(layer explore\\)")
  message(FATAL_ERROR "the layer check failed without naming the file and layers:\n${err}")
endif()
if(err MATCHES "fine.hpp")
  message(FATAL_ERROR "the layer check refused a higher layer including a lower one:\n${err}")
endif()
message(STATUS "layer check refused the violation: ${err}")
