// The rig's calibration: the model (rig_model.hpp) and its file (calibration_file.hpp).
#pragma once

#include "slproto/calibration_file.hpp"
#include "slproto/rig_model.hpp"
