// being written: hidden features (issue 4)
