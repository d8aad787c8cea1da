"""What a user writes against the MRI system (pure core): the dynamics model, the observers, the controllers, the
references and routes; each kind on any number of axes, with its compiled step."""
