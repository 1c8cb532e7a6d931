"""The discrepancy workflow (issue 7): find where model and measurement disagree, name the missing effect, add it."""
