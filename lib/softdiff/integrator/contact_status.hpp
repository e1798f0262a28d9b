#pragma once
// The step's contact solve as a StepStatus (contact_not_converged at step k, or ok), with
// the text `simulate` warns with (or fails with under --strict) and the Python module
// raises or warns with: the solver, the contact count, its iterations and residuals
// against the tolerance (docs/cli.md "Exit codes").
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <functional>
#include <sstream>
#include <string>

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

// The runs' rule for a step's status (simulate's output run and control's run; --strict):
// what stops the run, or ok. A Newton iteration that did not converge (not_converged) and
// an unconverged contact solve stop it under strict; otherwise they are counted in
// newton_warnings / contact_warnings and the first of each is passed to warn (then
// counted, not shown). Any other failure stops the run.
inline StepStatus strict_or_warn(const Model& model, const Data& data, long k, StepStatus s, bool strict,
                                 long& newton_warnings, long& contact_warnings,
                                 const std::function<void(const std::string&)>& warn) {
  if (s.code == StepStatus::Code::not_converged) {
    if (strict) return s;
    if (newton_warnings++ == 0 && warn) warn(describe(model, s) + " (further such warnings are counted, not shown)");
  } else if (!s.ok()) {
    return s;
  }
  if (const StepStatus c = contact_status(model, data, k); !c.ok()) {
    if (strict) return c;
    if (contact_warnings++ == 0 && warn)
      warn(describe(model, c) + " (further such warnings are counted, not shown; --strict makes it an error)");
  }
  return {};
}

}  // namespace softdiff::integrator
