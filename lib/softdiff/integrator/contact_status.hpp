#pragma once
// The step's contact solve as a StepStatus (contact_not_converged at step k, or ok), with
// the text `simulate` warns with (or fails with under --strict) and the Python module
// raises or warns with: the solver, the contact count, its iterations and residuals
// against the tolerance (docs/cli.md "Exit codes").
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <sstream>

namespace softdiff::integrator {

inline StepStatus contact_status(const Model& model, const Data& data, long k) {
  StepStatus c;
  const auto& cd = data.contact;
  if (!model.contact.enabled || cd.result.converged) return c;
  c.code = StepStatus::Code::contact_not_converged;
  c.step = k;
  std::ostringstream d;
  d.precision(3);
  d << (model.contact.ncp.solver == contact::NcpSolverKind::admm ? "ADMM" : "PGS") << ", " << cd.contacts.size()
    << " contacts, " << cd.result.iterations << " iterations: residuals primal " << cd.result.residuals.primal
    << ", dual " << cd.result.residuals.dual << ", complementarity " << cd.result.residuals.complementarity
    << " > tolerance " << model.contact.ncp.tolerance;
  c.detail = d.str();
  return c;
}

}  // namespace softdiff::integrator
