// The error contract in what a player sees (docs/DATABASE.md, "The error contract"): how far a
// clip's decoded frames are from the frames it was encoded from, as three figures a viewer notices
// differently. A smooth offset of a few mm is invisible; noise that changes from frame to frame
// (flicker) shows at a tenth of that, so jitter gets its own cap.
//  - rms: per frame, the RMS over vertices of the vertex distance |decoded - original|; the worst
//    frame's.
//  - max: the largest vertex distance over every vertex and frame.
//  - jitter: per vertex, the length of the second difference over frames of the coding error,
//    |e[f+1] - 2 e[f] + e[f-1]| with e = decoded - original (the error's acceleration times dt^2);
//    the largest over vertices and frames 1..F-2 (0 for clips under 3 frames).
// Plain C++ over float frames (frame-major, x y z per vertex), so the encoder, `db check`, the
// benchmarks and the tests measure the same thing.
#pragma once

#include <cstdint>
#include <string>

namespace clothdb::codec {

struct ContractFigures {
  double rms = 0;     // m, worst frame's RMS vertex distance
  double max = 0;     // m, largest vertex distance
  double jitter = 0;  // m, largest second difference of the error
};

// The caps a file or clip promises (0: no cap on that figure).
struct Contract {
  double rms = 0;
  double max = 0;
  double jitter = 0;
};

// Jitter cap when none is given (m): 0.1 mm, where frame-to-frame noise starts to show on cloth
// (docs/notebook/codec_v3.md).
constexpr double kDefaultJitterCap = 0.0001;

// Measures decoded against original, both frame_count x vertex_count x 3 floats.
ContractFigures measure_contract(const float* decoded, const float* original, uint32_t frame_count,
                                 uint32_t vertex_count);

// Whether every figure is within its cap (a cap of 0 is not checked). `tolerance` (relative) allows
// for the figures having been stored as text or float.
bool within(const ContractFigures& figures, const Contract& caps, double tolerance = 0);

// "RMS 0.81 / max 2.9 / jitter 0.09 mm", for messages and listings.
std::string describe(const ContractFigures& figures);

}  // namespace clothdb::codec
