"""The real cell's controller over Robot Web Services: state, start and stop of the EGM kit."""
