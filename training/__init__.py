"""Training of the learned decision stage: data, model, report (never imported at run time)."""
