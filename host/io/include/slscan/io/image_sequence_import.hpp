// Importing a structured-light image sequence made by another scanner: a folder of images
// (PNG, BMP, TIFF, JPG; 8 or 16 bit) plus a JSON description of what each image shows,
// turned into one of our capture files, exactly as `slscan scan` records one view of one
// projector (ScanRequest, the frames in plan order, ScanDone), so `slscan reprocess` decodes
// it through the same pipeline. The description format is in docs/real-data.md:
//
//   { "projector": {"width": 1824, "height": 1140}, "axis": "columns",
//     "camera": {"width": 1688, "height": 1352, "bit_depth": 8},          (optional, checked)
//     "white": "frameSeq_00.bmp", "black": "frameSeq_01.bmp",             (optional pair)
//     "gray": {"files": {"pattern": "frameSeq_%02d.bmp", "first": 2, "count": 10},
//              "inverse_files": [...],                                    (optional, same count)
//              "bit_order": "msb_first", "bits_not_projected": 1,
//              "convention": "centre"},                                   (or "slstudio")
//     "phase": {"files": [...], "period_px": 16},                         (optional)
//     "complementary": "c.png", "complementary_inverse": "ci.png" }       (optional, with phase)
//
// The Gray frames show the reflected Gray code of the projector coordinate, of which the
// `bits_not_projected` least significant bits are left out; since the top bits of gray(x)
// are gray(x >> s), that is our plan with period_px = 2^s and no phase steps. Inverse frames
// become the plan's inverse_gray; the convention its gray_low_bits.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "slproto/pattern_plan.hpp"

namespace slscan::io {

struct SequenceDescription {
  slproto::PatternPlanConfig plan;          // the plan the images follow
  std::vector<std::string> files;           // one per plan pattern, in plan order, resolved paths
  int bit_depth = 8;                        // of the images' values: 8, 10, 12 or 16
  int camera_width = 0, camera_height = 0;  // 0: not stated (taken from the images)
  // "calibration_keys": the calibration file's names for its entries (foreign_calibration.hpp).
  std::map<std::string, std::string> calibration_keys;
};

// Parses the description; relative file names resolve against `base_dir`. Throws IoError
// naming `origin` and the bad or missing field.
SequenceDescription parse_sequence_description(const std::string& json_text, const std::string& base_dir,
                                               const std::string& origin = "description");
SequenceDescription load_sequence_description(const std::string& path);

struct ImportedSequence {
  slproto::PatternPlan plan;
  int width = 0, height = 0;
  int bit_depth = 8;  // as stored in the frames: 8, 10 or 12 (16-bit images are reduced to 12)
  int source_bit_depth = 8;
  std::vector<std::vector<std::uint8_t>> frames;  // plan order; tightly packed, uint16 LE when bit_depth > 8
};

// Images already read, by path (grey, as read): `import --detect` reads each file once while it
// tries many descriptions of the same images.
struct ImageCache {
  struct Image {
    int width = 0, height = 0, depth = 0;  // depth: 8 or 16 (bits per sample as stored)
    std::vector<std::uint8_t> bytes;       // tightly packed, uint16 LE for 16 bits
  };
  std::map<std::string, Image> images;
};

// Reads every image and checks it against the description and against each other: count,
// size, bit depth, channels. Throws IoError saying what differs ("frameSeq_05.bmp is
// 1600 x 1200, the description says 1688 x 1352").
ImportedSequence read_image_sequence(const SequenceDescription& description, ImageCache* cache = nullptr);

// Writes the sequence as a capture of one view (angle 0) of projector 0.
void write_imported_capture(const std::string& path, const ImportedSequence& sequence);

}  // namespace slscan::io
