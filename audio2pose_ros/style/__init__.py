"""Speaking styles: measured figures, presets, personal models (enrolment) and their evaluation."""
