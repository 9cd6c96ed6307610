"""What the views show, computed without Qt: one module per view (issue 25.1). The app's feeds run these on
workers and hand the results to the widgets."""
