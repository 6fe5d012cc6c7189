// The reconstruction parameters of a run: defaults, overridden by a JSON config file whose
// every key is checked (a misspelt key is an error, not silently ignored).
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "slscan/core/scan_reconstruction.hpp"

namespace slscan::app {

// Applies a JSON object to the options; throws std::invalid_argument naming the key.
void apply_config(const nlohmann::json& config, core::ReconstructionOptions& options);
core::ReconstructionOptions load_config(const std::string& path);  // throws io::IoError / invalid_argument
// The effective parameters, for report.json (every output records what made it).
nlohmann::json config_to_json(const core::ReconstructionOptions& options);

}  // namespace slscan::app
