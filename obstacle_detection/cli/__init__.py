"""What the command lines in ``tools/`` share: exit codes, errors, warnings, a progress bar."""
