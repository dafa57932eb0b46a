"""From a specification to a batch of records: scenarios, the sampled-data closed loop, the Record
and Truth a method and the metrics see, and seeding."""
