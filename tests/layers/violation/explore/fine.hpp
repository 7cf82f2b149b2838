// Fixture: a higher layer including a lower one is allowed. Never compiled.
#pragma once
#include "cloth/mesh.hpp"
