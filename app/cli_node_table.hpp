// `canbridge nodes` output: the endpoint's node rows as an aligned table for operators.
#pragma once

#include <iosfwd>
#include <vector>

#include "app/cli_reply.hpp"

namespace canbridge::cli {

// Columns NET MODULE GATEWAY LOCAL SURFACE PROFILE KIND STATE HB_AGE_MS BOOTS EMCY, in the rows'
// order; "no nodes" when there are none.
void print_node_table(std::ostream& out, const std::vector<NodeRow>& rows);

}  // namespace canbridge::cli
