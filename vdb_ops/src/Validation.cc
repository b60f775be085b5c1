// being written: validation against analytic truths (issue 3)
