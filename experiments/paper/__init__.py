"""Tables and figures of the paper (Tables 2, 3, 4, 6 and Figure 5), with their protocol configs."""
