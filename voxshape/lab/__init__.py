"""The lab: experiments (lab.experiment), reports of runs (lab.report) and the demo (lab.demo),
putting the nodes' cores together."""
