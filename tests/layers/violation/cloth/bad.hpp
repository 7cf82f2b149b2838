// Fixture for the precompute layer check (tests/layers/expect_violation.cmake): the cloth layer
// must not include the explorer. Never compiled.
#pragma once
#include "explore/explorer.hpp"
