"""Import demonstrations into a :class:`pbicrl.inference.data.Dataset`.

* :func:`read_csv`, :func:`read_parquet`, :func:`read_table` - one row per state with trajectory id, group and
  feature columns; groups are integers (1 = best) or names in a given order (``group_order``). Parquet
  needs ``pip install "pbicrl[io]"``;
* :func:`from_minari` - a local Minari dataset plus a user feature function (needs ``pip install "minari[hdf5]"``;
  recording datasets with ``minari.DataCollector`` also needs ``pip install "minari[create]"``).

Optional dependencies are imported only when a reader is called.
"""

from __future__ import annotations

from pbicrl.io.csv import (TableError, check_delimiter, columns_to_dataset, read_csv, read_parquet, read_table,
                           write_csv)
from pbicrl.io.minari import from_minari, load_feature_function

__all__ = ["TableError", "check_delimiter", "columns_to_dataset", "read_csv", "read_parquet", "read_table",
           "write_csv", "from_minari", "load_feature_function"]
