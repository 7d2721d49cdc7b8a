"""Python package set-up of rths_study (ament_python)."""

from setuptools import find_packages, setup

package_name = 'rths_study'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='rths maintainers',
    maintainer_email='maintainers@rths.dev',
    description=open('package.xml').read().split('<description>')[1].split('</description>')[0],
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        # `rths study run` and `rths bench study`: rths_bringup's `rths` command finds this
        # module here (it sits below this package); the options it adds to rths_bench's
        # `rths bench rths-benchmark` go in its extend(), run after every register().
        'rths.cli': ['study = rths_study.cli'],
    },
)
